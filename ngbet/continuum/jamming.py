"""The jamming barrier of the continuum, an energy term evaluated only where it can matter.

The barrier (:func:`ngbet.continuum.physics.jamming_energy`, K_jam = max(K_el, K_sh)) is an energy
term like the others, but it is zero wherever the yarns are more open than the jamming angle, which
is everywhere in ordinary states, and evaluating it on every element is a large part of each
assembly. It is therefore an integrator of its own, defined on the elements of ``elements``: none
until a solved state (:meth:`JammingBarrier.watch`) brings the yarns closer than
:data:`JAMMING_MARGIN` times the threshold's sine at some integration point of the barrier's own
rule (none in ordinary states); from then on every element a solved state brought within
:data:`JAMMING_SET_MARGIN` times it, and all of them while a relaxation runs
(:meth:`JammingBarrier.switch_on`). On every other element the barrier and its derivatives are
exactly 0 at that state, so the energy and its equilibria are the same either way; a state
solved with the barrier off on an element whose yarns then close past the threshold is no
equilibrium (:meth:`JammingBarrier.missed`): it is solved again with the barrier on everywhere.
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

__all__ = ["JAMMING_MARGIN", "JAMMING_SET_MARGIN", "JammingBarrier"]

log = logging.getLogger(__name__)

#: the jamming barrier is evaluated once a state's yarns come closer than this multiple of the
#: jamming angle's sine (before, it is zero): about 29° for the default 5°, which the full model's
#: states do not reach on the embedded scene (smallest angle 35° at 56 mm); without bending its clamp
#: corners pass it at 18 mm (25°), an increment before they snap shut onto the barrier (19.8 mm)
JAMMING_MARGIN = 5.5
#: once on, the barrier is evaluated on every element whose yarns a solved state brought closer than
#: this multiple of the threshold's sine (the same 29° for the default 5°), for the rest of the run:
#: an element that comes near stays in, and one increment rarely closes yarns from there past the
#: threshold on an element not yet in (a miss, solved again with the barrier everywhere). With
#: 20° the corner of the first-gradient model, at 22° one increment before it snaps shut, was
#: outside the set and its snapping increments were misses (11 more factorizations to 56 mm)
JAMMING_SET_MARGIN = 5.5


class JammingBarrier:
    """The barrier's integrator on the forms of a problem, and the watch that switches it on.

    ``forms``: (bilinear form, linearized) pairs the energy term is added to (more with
    :meth:`add_to`); ``u``: the displacement whose yarn angle is watched. With ``effects.jamming``
    off nothing is added and :attr:`on` stays False.
    """

    def __init__(
        self,
        scene: Scene,
        mesh: ngs.Mesh,
        X: ngs.FESpace,
        u: Any,
        m1: CF,
        m2: CF,
        forms: Sequence[tuple[ngs.BilinearForm, bool]] = (),
    ) -> None:
        self.elements = ngs.BitArray(mesh.ne)
        self.elements.Clear()
        self._ne = mesh.ne
        self._where = np.zeros(mesh.ne, bool)  # ``elements`` as a mask
        self._near = np.zeros(mesh.ne, bool)  # the elements solved states brought within the set's margin
        self._check: tuple[CF, object] | None = None
        # u's coefficients (a view) and the last state checked with its smallest sines: the check
        # after a solve (missed) and the watch of the same state (converged) evaluate once
        self._u = u.vec.FV().NumPy() if hasattr(u, "vec") else None
        self._checked: tuple[np.ndarray, np.ndarray] | None = None
        self._energy: tuple[CF, int] | None = None  # the integrand and its bonus integration order
        self.s_jam = math.nan
        if not scene.effects.jamming:
            return
        sp, mat, disc = scene.specimen, scene.material, scene.discretization
        orientation = math.copysign(1.0, sp.m1[0] * sp.m2[1] - sp.m1[1] * sp.m2[0])
        self.s_jam = math.sin(math.radians(mat.jamming_angle_deg))

        def sine(grad_u: CF) -> CF:
            return physics.yarn_angle_sine(ngs.Id(2) + grad_u, m1, m2, orientation)

        W = physics.jamming_energy(sine(ngs.Grad(X.TrialFunction()[0])), max(mat.K_el, mat.K_sh), self.s_jam).Compile()
        self._energy = (W, 2 + disc.quad_bonus)
        self.add_to(forms)
        # the integrator's own rule: order 2 max(p) + bonus over the compound element (NGSolve's SymbolicEnergy)
        order = 2 * max(c.globalorder for c in X.components) + 2 + disc.quad_bonus
        rule = ngs.IntegrationRule(ngs.TRIG, order)
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
        """Whether the barrier is evaluated on some element (a state came near it, or a relaxation runs)."""
        return bool(self._where.any())

    @property
    def patch(self) -> np.ndarray | None:
        """The elements the barrier is on (a mask), None where it is on none or on every element."""
        if not self._where.any() or self._where.all():
            return None
        return self._where

    def holds(self) -> bool:
        """Whether the current state has yarns closer than the jamming angle on an element the barrier is on.

        One evaluation of the yarn angle's sine at the barrier's integration points (none while the
        barrier is on no element); nan (a degenerate state) counts as holding.
        """
        if self._check is None or not self._where.any():
            return False
        return not bool(np.all(self._smallest()[self._where] >= self.s_jam))

    def switch_on(self) -> None:
        """Evaluate the barrier on every element until the next solved state (:meth:`watch`)."""
        self.elements.Set()
        self._where[:] = True

    def _smallest(self) -> np.ndarray:
        """The smallest sine of the yarn angle in each element, at the barrier's integration points (nan kept)."""
        assert self._check is not None
        if self._u is not None and self._checked is not None and np.array_equal(self._checked[0], self._u):
            return self._checked[1]
        s, points = self._check
        smallest: np.ndarray = np.asarray(s(points)).reshape(self._ne, -1).min(axis=1)
        if self._u is not None:
            self._checked = (self._u.copy(), smallest)
        return smallest

    def missed(self) -> bool:
        """Whether the state has yarns closer than the jamming angle on an element the barrier is off on.

        There the barrier is not zero: the state is no equilibrium of the energy (past parallel
        the shear energy falls again, and Newton can land there in one increment, from yarns more
        open than :data:`JAMMING_MARGIN` s_jam at the last state). False while the barrier is on everywhere.
        """
        if self._check is None or self._where.all():
            return False
        off = self._smallest()[~self._where]
        return not bool(np.all(off > self.s_jam))  # nan (a degenerate state) counts as missed

    def watch(self) -> None:
        """Switch the barrier on once a solved state comes within :data:`JAMMING_MARGIN` s_jam, on the elements near.

        From then on it is evaluated on every element a solved state brought within
        :data:`JAMMING_SET_MARGIN` s_jam.
        Called at each converged state of the path (:meth:`ContinuumProblem.converged`): one
        evaluation of the yarn angle's sine at the integration points, no assembly. The state is
        exact either way (the barrier is zero above s_jam); the elements it is on are those the
        states brought near the threshold, so that its cost is that of the few elements there. A
        relaxation (or a miss) switches it on everywhere until the next solved state (:meth:`switch_on`).
        """
        if self._check is None:
            return
        smallest = self._smallest()
        if not self.on:
            if bool(np.all(smallest >= JAMMING_MARGIN * self.s_jam)):  # nan (a degenerate state) counts as near
                return
            low = float(np.nanmin(smallest)) if np.isfinite(smallest).any() else math.nan
            angle = math.degrees(math.asin(max(-1.0, min(1.0, low)))) if math.isfinite(low) else math.nan
            log.info(
                "the jamming barrier is on: %s",
                f"the yarns close to {angle:.3g} degrees" if angle > 0 else "the yarns of a solved state cross",
            )
        self._near |= ~(smallest >= JAMMING_SET_MARGIN * self.s_jam)
        if np.array_equal(self._near, self._where):
            return
        self._where = self._near.copy()
        self.elements.Clear()
        for i in np.flatnonzero(self._where):
            self.elements[int(i)] = True
