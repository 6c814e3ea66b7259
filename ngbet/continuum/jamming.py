"""The jamming barrier of the continuum, an energy term evaluated only where it can matter.

The barrier (:func:`ngbet.continuum.physics.jamming_energy`, K_jam = max(K_el, K_sh)) is an energy
term like the others, but it is zero wherever the yarns are more open than the jamming angle, which
is everywhere in ordinary states, and evaluating it on every element is a large part of each
assembly. It is therefore an integrator of its own, defined on the elements of ``elements``: none
until a solved state brings the yarns within :data:`JAMMING_MARGIN` times the threshold's sine
somewhere (:meth:`JammingBarrier.watch`) or a relaxation begins (:meth:`JammingBarrier.switch_on`),
all from then on. Until then it is exactly 0 with its
derivatives, so the energy is the same either way.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

import ngsolve as ngs
import numpy as np
from ngsolve import CoefficientFunction as CF

from ..scene.document import Scene
from . import physics

__all__ = ["JAMMING_MARGIN", "JammingBarrier"]

log = logging.getLogger(__name__)

#: the jamming barrier is evaluated once a state's yarns come closer than this multiple of the
#: jamming angle's sine (before, it is zero): twice, i.e. about 10° for the default 5°, which no
#: ordinary state reaches (smallest angle 35° on the embedded scene at 56 mm, 18° at 66 mm)
JAMMING_MARGIN = 2.0

class JammingBarrier:
    """The barrier's integrator on the forms of a problem, and the watch that switches it on.

    ``forms``: (bilinear form, linearized) pairs the energy term is added to (more with
    :meth:`add_to`); ``u``: the displacement whose yarn angle is watched. With ``effects.jamming``
    off nothing is added and :attr:`on` stays False.
    """

    def __init__(self, scene: Scene, mesh: ngs.Mesh, X: ngs.FESpace, u: Any, m1: CF, m2: CF,
                 forms: Sequence[tuple[ngs.BilinearForm, bool]] = ()) -> None:
        self.elements = ngs.BitArray(mesh.ne)
        self.elements.Clear()
        self._check: tuple[CF, object] | None = None
        self._energy: tuple[CF, int] | None = None  # the integrand and its bonus integration order
        self.s_jam = math.nan
        if not scene.effects.jamming:
            return
        sp, mat, disc = scene.specimen, scene.material, scene.discretization
        orientation = math.copysign(1.0, sp.m1[0] * sp.m2[1] - sp.m1[1] * sp.m2[0])
        self.s_jam = math.sin(math.radians(mat.jamming_angle_deg))

        def sine(grad_u: CF) -> CF:
            return physics.yarn_angle_sine(ngs.Id(2) + grad_u, m1, m2, orientation)

        W = physics.jamming_energy(sine(ngs.Grad(X.TrialFunction()[0])), max(mat.K_el, mat.K_sh),
                                   self.s_jam).Compile()
        self._energy = (W, 2 + disc.quad_bonus)
        self.add_to(forms)
        rule = ngs.IntegrationRule(ngs.TRIG, 2 * max(disc.p_u, 1) + disc.quad_bonus)
        self._check = (sine(ngs.Grad(u)).Compile(), mesh.MapToAllElements(rule, ngs.VOL))

    def add_to(self, forms: Sequence[tuple[ngs.BilinearForm, bool]]) -> None:
        """Add the barrier's integrator to each (bilinear form, linearized) pair (nothing when jamming is off)."""
        if self._energy is None:
            return
        W, bonus = self._energy
        before = ngs.ngsglobals.symbolic_integrator_uses_diff
        try:
            for form, symbolic in forms:
                ngs.ngsglobals.symbolic_integrator_uses_diff = symbolic
                form += ngs.SymbolicEnergy(W, ngs.VOL, bonus_intorder=bonus, definedonelements=self.elements)
        finally:
            ngs.ngsglobals.symbolic_integrator_uses_diff = before

    @property
    def on(self) -> bool:
        """Whether the barrier is evaluated (a state came near it, or a relaxation began)."""
        return bool(self.elements.NumSet())

    def switch_on(self) -> None:
        """Evaluate the barrier on every element from now on."""
        self.elements.Set()

    def missed(self) -> bool:
        """Whether the state, solved with the barrier off, has yarns closer than the jamming angle.

        There the barrier is not zero: the state is no equilibrium of the energy (past parallel
        the shear energy falls again, and Newton can land there in one increment, from yarns more
        open than :data:`JAMMING_MARGIN` s_jam at the last state). False while the barrier is on.
        """
        if self._check is None or self.on:
            return False
        s, points = self._check
        smallest = float(np.min(np.asarray(s(points))))
        return not smallest > self.s_jam  # nan (a degenerate state) counts as missed

    def watch(self) -> None:
        """Switch the barrier on for good once the yarns come within :data:`JAMMING_MARGIN` s_jam.

        Called at each converged state of the path (:meth:`ContinuumProblem.converged`): one
        evaluation of the yarn angle's sine at the integration points, no assembly. A state that comes
        within the margin is still exact (the barrier is zero above s_jam); the barrier holds from
        the next load on. A relaxation switches it on before it starts (:meth:`switch_on`).
        """
        if self._check is None or self.on:
            return
        s, points = self._check
        smallest = float(np.min(np.asarray(s(points))))
        if not smallest >= JAMMING_MARGIN * self.s_jam:  # nan (a degenerate state) counts as near
            angle = math.degrees(math.asin(max(-1.0, min(1.0, smallest)))) if math.isfinite(smallest) else math.nan
            log.info("the jamming barrier is on: %s", f"the yarns close to {angle:.3g} degrees" if angle > 0
                     else "the yarns of a solved state cross")
            self.switch_on()
