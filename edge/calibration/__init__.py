"""Calibration: pixels to world cm on the marker plane."""
