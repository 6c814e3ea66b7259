"""The errors ngbet raises, shared by both models.

``SceneError`` (ngbet.scene) is a bad scene; :class:`ConvergenceError` is a load that could not be
carried to the end. Both models raise the same :class:`ConvergenceError`, after the run folder has
recorded every converged step and ``summary.json`` says ``"status": "failed"``.
"""

from __future__ import annotations


class NgbetError(Exception):
    """Base of the errors ngbet raises on purpose."""


class ConvergenceError(NgbetError, RuntimeError):
    """The load could not be carried further.

    Attributes
    ----------
    last_converged_mm : float
        The last clamp displacement reached [mm] (its step is already on disk).
    """

    last_converged_mm: float = 0.0
