"""Baselines the hierarchical GPDM is compared with."""

from .amaya import apply_amaya, fit_amaya

__all__ = ["apply_amaya", "fit_amaya"]
