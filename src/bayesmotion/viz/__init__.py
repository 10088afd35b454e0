"""Figures and animations of motion, rollouts and posteriors (matplotlib)."""
