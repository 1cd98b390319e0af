"""Calibration: observing a simulation through measured markers and fitting its parameters."""
