"""The errors ngbet raises, shared by both models.

``SceneError`` (ngbet.scene) is a bad scene; :class:`ConvergenceError` is a load that could not be
carried to the end. Both models raise the same :class:`ConvergenceError` (from the one
continuation engine, :mod:`ngbet.numerics.engine`), after the run folder has recorded every converged step
and ``summary.json`` says ``"status": "failed"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = ["Attempt", "ConvergenceError", "FitWorkerError", "NgbetError"]


class NgbetError(Exception):
    """Base of the errors ngbet raises on purpose."""


class FitWorkerError(NgbetError, RuntimeError):
    """A fit's worker process ended without an answer (killed, out of memory, crashed): the fit stops.

    The other workers are ended; what was made before is kept. The commands exit 1 with its message,
    as a study with crashed cases does.
    """


@dataclass
class Attempt:
    """One trial increment of the load path (loads in metres of clamp displacement)."""

    u0_from: float
    u0_to: float
    converged: bool
    iterations: int
    reason: str = ""
    history: list[float] = field(default_factory=list)  # corrector decrements per iteration

    def describe(self) -> str:
        """One line: loads in mm, verdict, iterations, reason and decrements."""
        return (
            f"{self.u0_from * 1e3:.6g} -> {self.u0_to * 1e3:.6g} mm: {'ok' if self.converged else 'FAILED'} "
            f"after {self.iterations} it ({self.reason}); decrements "
            + ", ".join(f"{h:.2e}" for h in self.history[:12])
        )


class ConvergenceError(NgbetError, RuntimeError):
    """The load could not be carried further.

    Parameters
    ----------
    message : str
        What stopped the path.
    last_converged_mm : float
        The last clamp displacement reached [mm] (its step is already on disk).
    attempts : sequence of Attempt
        Every tried increment, oldest first.
    diagnosis : str
        What the corrector concluded (e.g. a lost stability with its lowest eigenvalue).
    detail : object, optional
        The structured diagnosis the text was written from, e.g. the continuum's
        :class:`ngbet.continuum.stability.StabilityDiagnosis`.
    path_info : dict, optional
        What the path met before it stopped, for ``summary.json`` (e.g. the instabilities an
        arc-length continuation passed, :attr:`ngbet.numerics.engine.PathResult.path_info`).

    Attributes
    ----------
    last_converged_mm, attempts, diagnosis, detail, path_info
        As given.
    """

    def __init__(
        self,
        message: str,
        last_converged_mm: float,
        attempts: Sequence[Attempt] = (),
        diagnosis: str = "",
        detail: object | None = None,
        path_info: dict[str, object] | None = None,
    ) -> None:
        self.last_converged_mm = float(last_converged_mm)
        self.attempts = list(attempts)
        self.diagnosis = diagnosis
        self.detail = detail
        self.path_info: dict[str, object] = dict(path_info or {})
        tail = "\n".join("  " + a.describe() for a in self.attempts[-8:])
        super().__init__(
            f"{message}\nlast converged load: {self.last_converged_mm:.6g} mm"
            + (f"\ndiagnosis: {diagnosis}" if diagnosis else "")
            + (f"\nlast attempts:\n{tail}" if tail else "")
        )
