"""Calibration of the continuum model on measured BET curves: data, shear tables, joint fits, predictions."""

__all__: list[str] = []
