r"""Newton on the unknowns of the jamming barrier's elements with the rest held: the contact solved first.

Where the barrier holds the yarns (the clamp corners of the first-gradient model, which close onto it
at about 20 mm of the embedded scene), its energy K s_jam² (1 − t)³/t, and its quadratic
continuation in t below the cutoff, is far stiffer than the rest and strongly nonlinear in ∇u:
Newton's full steps, with a tangent exact to round-off, contract the residual there by only
0.1–0.4 per iteration, and after each step the residual lives on the unknowns of those few
elements alone (bench/README.md, *The first-gradient model in contact*). :class:`BarrierPatch`
drives that residual to zero first, by a Newton iteration of its own on those unknowns, the rest of
the state held (nonlinear elimination): the linearization of the elements that touch them only,
and a factorization of that small block. The global Newton then sees the smooth remainder of the
problem and takes one or two iterations per increment where it took three to seven.

The equilibrium is the same: a local iteration changes the state, not the energy, and every
increment still ends on Newton's own test of the global decrement (:func:`ngbet.numerics.newton.newton`).
The energy's integrands are those of the problem (its parts, with the integration order of its
measure; the barrier's own integrator through :meth:`JammingBarrier.add_to`), so that the local
residual is the global one on the patch's rows, to round-off.

Only for a problem without a multiplier (the first-gradient model), whose Newton matrix is the
energy's Hessian: the local block is then factorized like the global one.
"""

from __future__ import annotations

import time

import ngsolve as ngs
import numpy as np

from .problem import ContinuumProblem

__all__ = ["LOCAL_ITERATIONS", "BarrierPatch"]

#: local Newton iterations at most per call of :meth:`BarrierPatch.settle`
LOCAL_ITERATIONS = 12


class BarrierPatch:
    """The barrier's elements of a problem: their free unknowns and the energy of the elements touching them.

    Built on demand for each set of elements the barrier is on (:attr:`JammingBarrier.patch`); counts
    its local iterations (``iterations``) and their time (``time_s``).
    """

    def __init__(self, problem: ContinuumProblem) -> None:
        if "lam" in problem.field_names:
            raise ValueError("the barrier's patch is solved for problems without a multiplier only")
        self.problem = problem
        self.iterations = 0
        self.time_s = 0.0
        self._parts: list[ngs.CoefficientFunction] = []  # the energy's parts, compiled when first needed
        self._key: bytes | None = None
        self._form: ngs.BilinearForm | None = None
        self._inverse: ngs.BaseMatrix | None = None  # the factorization of the patch's block, its analysis kept
        self._rows = np.zeros(0, dtype=np.int64)
        self._bits = ngs.BitArray(problem.X.ndof)
        self._ext = ngs.BitArray(problem.mesh.ne)
        self._table: np.ndarray | None = None  # element -> its dofs (padded with −1)
        vec = problem.gf.vec
        self._r, self._d = vec.CreateVector(), vec.CreateVector()

    def _dof_table(self) -> np.ndarray:
        if self._table is None:
            X, mesh = self.problem.X, self.problem.mesh
            dofs = [list(X.GetDofNrs(ngs.ElementId(ngs.VOL, i))) for i in range(mesh.ne)]
            width = max(len(d) for d in dofs)
            self._table = np.array([d + [-1] * (width - len(d)) for d in dofs], dtype=np.int64)
        return self._table

    def _build(self, elements: np.ndarray) -> None:
        """The patch's rows (the free unknowns of ``elements``) and the energy of the elements touching them."""
        pb = self.problem
        table = self._dof_table()
        rows = np.unique(table[elements])
        rows = rows[rows >= 0]
        self._rows = rows[pb.free_all[rows]]
        touching = np.isin(table, self._rows).any(axis=1)
        self._bits.Clear()
        for i in self._rows:
            self._bits[int(i)] = True
        self._ext.Clear()
        for i in np.flatnonzero(touching):
            self._ext[int(i)] = True
        if not self._parts:
            self._parts = [cf.Compile() for cf in pb.energy_parts]
        # a form of its own per patch: NGSolve builds a matrix's graph from the elements it is defined on
        form = ngs.BilinearForm(pb.X, symmetric=True)
        before = ngs.ngsglobals.symbolic_integrator_uses_diff
        try:
            ngs.ngsglobals.symbolic_integrator_uses_diff = True
            bonus = pb.scene.discretization.quad_bonus
            for cf in self._parts:
                form += ngs.SymbolicEnergy(cf, ngs.VOL, bonus_intorder=bonus, definedonelements=self._ext)
        finally:
            ngs.ngsglobals.symbolic_integrator_uses_diff = before
        pb.jamming.add_to([(form, True)])
        self._form, self._inverse = form, None

    @property
    def rows(self) -> np.ndarray:
        """The free unknowns of the patch last built (indices into the state)."""
        return self._rows

    def residual(self) -> np.ndarray:
        """The residual of the patch's energy at the current state, full length (exact on :attr:`rows`)."""
        assert self._form is not None
        self._form.Apply(self.problem.gf.vec, self._r)
        return np.array(self._r.FV().NumPy())

    def settle(self, tol: float, r: np.ndarray, max_iterations: int = LOCAL_ITERATIONS) -> int:
        """Newton on the patch's unknowns, the rest held, until its decrement |d·r| ≤ ``tol``; the iterations taken.

        ``r``, the problem's residual at the state of the call, is brought to the state settled in
        place: only the elements touching the patch's unknowns contribute to its change, which is
        that of the patch's residual (exact to round-off). 0 (state and ``r`` untouched) where the
        barrier is on no element or on all of them (a relaxation), where it holds no yarns (their
        angle above the threshold at its integration points: nothing stiff to solve first, as for the
        corner before it snaps shut), and where the local iteration stops contracting or leaves the
        finite numbers: the global Newton goes on from the state of the call as without the patch.
        """
        elements = self.problem.jamming.patch
        if elements is None or not self.problem.jamming.holds():
            return 0
        t0 = time.process_time()
        key = elements.tobytes()
        if key != self._key:
            self._build(np.flatnonzero(elements))
            self._key = key
        if self._rows.size == 0:  # the barrier's elements have no free unknowns
            return 0
        assert self._form is not None
        x, rows, vec = self.problem.x, self._rows, self.problem.gf.vec
        start = x[rows].copy()
        before: np.ndarray | None = None  # the patch's residual at the state of the call
        last = np.inf
        taken = 0
        for taken in range(1, max_iterations + 1):
            self._form.AssembleLinearization(vec)
            if self._inverse is None:
                self._inverse = self._form.mat.Inverse(self._bits, inverse="sparsecholesky")
            else:  # the same pattern: its analysis reused
                self._inverse.Update()
            inverse = self._inverse
            self._form.Apply(vec, self._r)
            if before is None:
                before = np.array(self._r.FV().NumPy())
            self._d.data = inverse * self._r
            d, rp = self._d.FV().NumPy()[rows], self._r.FV().NumPy()[rows]
            delta = abs(float(d @ rp))
            if not np.isfinite(delta) or delta >= last:
                taken = 0
                break
            x[rows] -= d
            last = delta
            if delta <= tol:
                break
        if taken > 0:
            after = self.residual()
            if np.all(np.isfinite(after)):
                assert before is not None
                r += after - before
            else:
                taken = 0
        if taken == 0:
            x[rows] = start
        self.iterations += taken
        self.time_s += time.process_time() - t0
        return taken
