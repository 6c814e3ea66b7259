"""Measured curves: the one reader of laboratories' tables (columns, units, specimen, test) and the curves it gives.

Below the models and the commands: it knows the scene's refusal (:class:`ngbet.scene.validate.SceneError`)
and the ideal kinematics of the two tests (:mod:`ngbet.kinematics`), nothing above them, so the figures,
the calibration and the normalisation method read the same curves the same way.
"""

__all__: list[str] = []
