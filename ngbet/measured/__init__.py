"""Measured data: the one reader of laboratories' tables, the curves, shear angles and profiles it gives.

A table's columns, units, specimen and test are read in :mod:`.table`; the curves in :mod:`.curves`,
measured centre shear angles and mid-axis profiles in :mod:`.observations`.

Below the models and the commands: it knows the scene's refusal (:class:`ngbet.scene.validate.SceneError`)
and the ideal kinematics of the two tests (:mod:`ngbet.kinematics`), nothing above them, so the figures,
the calibration and the normalisation method read the same curves the same way.
"""

__all__: list[str] = []
