"""Calibration: how well each method places the sensors, and drift detection."""
