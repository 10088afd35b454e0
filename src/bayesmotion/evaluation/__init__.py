"""Evaluation: leave-one-out emotion inference with calibration, and naturalness measures of
motion (jerk, foot sliding, joint limits)."""
