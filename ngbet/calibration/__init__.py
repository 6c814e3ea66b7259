"""Calibration of the continuum model on measured curves: shear tables, joint fits, predictions."""

__all__: list[str] = []
