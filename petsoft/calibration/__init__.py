"""Calibration: fitting model parameters to recorded marker trajectories."""
