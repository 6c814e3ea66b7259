"""The continuum's linear algebra: the Newton matrix, its condensation, factorization and solves.

:class:`NewtonLinearSolver` owns what is numerics, not formulation: whether element-local dofs (Λ)
are condensed out before factorizing, the sparse inverse, the augmented Newton matrix of the exact
Lagrange method, and the time and count of every assembly, factorization and solve. It is the
linear algebra of a problem's :class:`~ngbet.continuum.solver.ContinuumSolver`.

Augmentation. The exact Lagrangian's Λ-Λ block is zero, so Λ cannot be condensed from it. With
condensation the Newton matrix is therefore that of the mixed penalty with a very large
K_aug = :data:`LAGRANGE_AUGMENTATION` K_ref (Λ(φ − i8) − Λ²/2K_aug), while the residual stays the
exact Lagrangian's: Newton converges to the exact saddle point, the O(1/K_aug) Jacobian error only
slows the last digits.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Sequence
from contextvars import ContextVar
from typing import TYPE_CHECKING, Protocol

import ngsolve as ngs
import numpy as np

from .compiled import add_energy

if TYPE_CHECKING:
    import scipy.sparse as sps

__all__ = [
    "CHOLMOD_MIN_DOFS",
    "LAGRANGE_AUGMENTATION",
    "LinearSolver",
    "NewtonLinearSolver",
    "assembly_thread_count",
    "assembly_threads",
    "energy_form",
    "pick_inverse",
]

#: K_aug / K_ref for the condensed Newton matrix of the exact Lagrange method: large enough that
#: the Jacobian error (relative size ~ K_sh / K_aug) leaves Newton quadratic to the tolerance,
#: small enough that the condensed matrix keeps ~8 correct digits.
LAGRANGE_AUGMENTATION = 1e6


#: NGSolve threads of a linearization (assembly and factorization) in a TaskManager of its own
#: (0: the surrounding one)
_ASSEMBLY_THREADS: ContextVar[int] = ContextVar("assembly_threads", default=0)


@contextlib.contextmanager
def assembly_threads(n: int) -> Iterator[None]:
    """Inside: each linearization is assembled and factorized in a TaskManager of its own (``n`` threads).

    The caller sets NGSolve's thread count (``ngsolve.SetNumThreads(n)``); everything else (solves,
    residuals) runs where it is called, serial outside a TaskManager. The threaded tangent equals
    the serial one to round-off (the order of the sparse adds).
    """
    token = _ASSEMBLY_THREADS.set(n)
    try:
        yield
    finally:
        _ASSEMBLY_THREADS.reset(token)


def assembly_thread_count() -> int:
    """NGSolve threads of a linearization (assembly, factorization): :func:`assembly_threads` or the surrounding."""
    return _ASSEMBLY_THREADS.get() or ngs.GetNumThreads()


#: "auto" factorizes with CHOLMOD from this many factorized dofs on (where cvxopt is installed):
#: below it the LLᵀ's symbolic analysis and cvxopt's import eat the gain (docs/numerics.md)
CHOLMOD_MIN_DOFS = 20_000


def pick_inverse(choice: str, indefinite: bool, condensed: bool = True, n_dofs: int = 0) -> str:
    """The sparse inverse of ``solver.linear_solver`` for a matrix of ``n_dofs`` factorized dofs.

    "auto": the uncondensed exact saddle point (``indefinite``: a zero Λ-Λ block) gets UMFPACK.
    A condensed matrix, positive definite at a stable state, of at least :data:`CHOLMOD_MIN_DOFS`
    dofs gets CHOLMOD's LLᵀ where cvxopt is installed (:mod:`ngbet.cholmod`; a matrix that is not
    positive definite goes to the sparse LDLᵀ); the others get the sparse LDLᵀ, which needs no
    zero pivots (an uncondensed mixed penalty has a negative Λ-Λ block).
    """
    if choice != "auto":
        return choice
    if indefinite:
        return "umfpack"
    from .. import cholmod

    big = condensed and n_dofs >= CHOLMOD_MIN_DOFS
    return "cholmod" if big and cholmod.available() else "sparsecholesky"


def energy_form(X: ngs.FESpace, inverse: str, condense: bool) -> ngs.BilinearForm:
    """An empty symmetric form on ``X`` whose matrix ``inverse`` can factorize.

    NGSolve stores a symmetric form's matrix in full unless asked; for the sparse LDLᵀ
    ("sparsecholesky"), which reads the lower triangle only, the form stores just that: half
    the sparse adds of each assembly and half the memory. UMFPACK gets the full matrix
    (given the lower triangle of the uncondensed saddle point it reports it singular), and so
    does a mesh with levels (refined): there NGSolve's symmetric storage allocates a new matrix
    at each assembly until it holds one per level, each to be factorized anew.
    """
    lower = inverse in ("sparsecholesky", "cholmod") and X.mesh.levels == 1
    return ngs.BilinearForm(X, symmetric=True, symmetric_storage=lower, condense=condense)


class LinearSolver(Protocol):
    """The linear algebra of a Newton matrix: linearize at a state, factorize, solve (NGSolve's ``inverse=``).

    What a problem's solver (:class:`ngbet.continuum.solver.ContinuumSolver`) and the stability
    test (:mod:`ngbet.continuum.stability`) ask of it; :class:`NewtonLinearSolver` is the one there is.
    """

    #: whether element-local dofs are condensed out before factorizing
    condensed: bool
    #: the sparse inverse in use ("sparsecholesky", "umfpack", "cholmod", ...)
    inverse_type: str
    #: K_aug of the augmented Newton matrix (0 when not augmented) [Pa]
    K_aug: float
    #: the form whose matrix is factorized (its harmonic extension carries the condensed dofs)
    form: ngs.BilinearForm
    #: the dofs the Newton matrix is factorized on (after condensation)
    freedofs: ngs.BitArray
    #: wall time [s] of the assemblies, factorizations and solves, and their counts
    timers: dict[str, float]
    counts: dict[str, int]

    @property
    def mat(self) -> ngs.BaseMatrix:
        """The assembled Newton matrix (condensed: the Schur complement on the coupling dofs)."""

    def factorize(self, state: ngs.BaseVector, shift: float = 0.0) -> float:
        """Linearize at ``state`` and factorize (shifted by s|diag| with s ≥ ``shift`` > 0); returns s."""

    def solve_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """Out = J⁻¹ r (free dofs), condensation handled; r is overwritten."""

    def extend(self, vec: ngs.BaseVector) -> None:
        """Add the condensed local dofs that follow the coupling dofs of ``vec``."""

    def free_matrix(self) -> tuple[sps.csr_matrix, np.ndarray]:
        """The free block of the Newton matrix as a full symmetric scipy matrix, and the free dofs."""


class NewtonLinearSolver:
    """Linearize, factorize and solve with the Newton matrix of an energy form.

    Parameters
    ----------
    form : ngsolve.BilinearForm
        The problem's energy form (``Variation``); its residual is the exact one.
    condense : bool
        Condense element-local dofs before factorizing (``solver.condense``).
    choice : str
        ``solver.linear_solver`` ("auto" picks by definiteness).
    saddle_energy : callable, optional
        For an exact saddle point (zero Λ-Λ block): K_aug -> the integrand of the augmented
        energy (in parts, as :func:`ngbet.numerics.compiled.add_energy` takes it) whose Hessian
        serves as the condensed Newton matrix.
    K_ref : float
        The stiffness that scales K_aug [Pa].
    dx : ngsolve measure
        The integration measure of the energy.
    compile_mode : str
        How the augmented integrand is compiled (:func:`ngbet.numerics.compiled.compile_energy`):
        the mode the energy got, so that "auto" does not mix.
    """

    def __init__(
        self,
        form: ngs.BilinearForm,
        condense: bool,
        choice: str,
        saddle_energy: Callable[[float], Sequence[ngs.CoefficientFunction]] | None = None,
        K_ref: float = 1.0,
        dx: object = None,
        compile_mode: str = "interpret",
    ) -> None:
        X = form.space
        self.K_aug = 0.0
        self.inverse_type = pick_inverse(
            choice, saddle_energy is not None and not condense, condense, X.FreeDofs(condense).NumSet()
        )
        if saddle_energy is not None and condense:
            self.K_aug = LAGRANGE_AUGMENTATION * K_ref
            self.form = energy_form(X, self.inverse_type, condense=True)
            add_energy(self.form, saddle_energy(self.K_aug), dx, compile_mode, X.ndof)
        else:
            self.form = form
        self.condensed = bool(self.form.condense)
        self.freedofs = X.FreeDofs(self.condensed)
        self._inv: ngs.BaseMatrix | None = None
        self._factorized: ngs.BaseMatrix | None = None  # the matrix self._inv factorizes
        self._llt: _FreeCholesky | None = None  # "cholmod": the LLᵀ of the free block
        self._use_llt = False  # the last matrix is factorized by self._llt (else by self._inv)
        self._diag: tuple[ngs.BaseMatrix, np.ndarray] | None = None  # a matrix and its diagonal's value positions
        self.timers = {"assembly_s": 0.0, "factorization_s": 0.0, "solve_s": 0.0}
        self.counts = {"factorizations": 0, "solves": 0}
        if self.inverse_type == "cholmod":
            self.counts["factorizations_ldlt"] = 0  # matrices not positive definite: the LDLᵀ

    @property
    def mat(self) -> ngs.BaseMatrix:
        """The assembled Newton matrix (condensed: the Schur complement on the coupling dofs)."""
        return self.form.mat

    def factorize(self, state: ngs.BaseVector, shift: float = 0.0) -> float:
        """Linearize at ``state`` and factorize (the symbolic factorization is reused).

        ``shift`` > 0: factorize A + s |diag A| instead, s ≥ ``shift`` (the free diagonal raised in
        proportion to itself, a unit-free regularization for pseudo-transient continuation); where
        CHOLMOD is available s is raised (×4, from at least 1e-8) until the matrix is positive
        definite (its LLᵀ exists). Returns s.
        """
        threaded = ngs.TaskManager() if _ASSEMBLY_THREADS.get() > 1 else contextlib.nullcontext()
        with threaded:  # assembly and factorization: two long parallel regions
            t0 = time.perf_counter()
            self.form.AssembleLinearization(state)
            t1 = time.perf_counter()
            if shift > 0:
                shift = self._factor_shifted(shift)
            else:
                self._use_llt = self.inverse_type == "cholmod" and self._factor_llt()
                if not self._use_llt:
                    self._factor_ngsolve()
        self.timers["assembly_s"] += t1 - t0
        self.timers["factorization_s"] += time.perf_counter() - t1
        self.counts["factorizations"] += 1
        return shift

    def _factor_shifted(self, shift: float, max_shift: float = 1e6) -> float:
        """Factorize A + s|diag A| with the least s = shift·4ᵏ that is positive definite (CHOLMOD), or s = shift."""
        from .. import cholmod

        vals, pos = self._diagonal()
        diag = vals[pos].copy()
        while True:
            vals[pos] = diag + shift * np.abs(diag)
            if not cholmod.available():
                self._use_llt = False
                self._factor_ngsolve()
                return shift
            mat = self.form.mat
            if self._llt is None or self._llt.mat is not mat:
                self._llt = _FreeCholesky(mat, self.freedofs)
            if self._llt.factor() or shift >= max_shift:
                self._use_llt = True
                return shift
            shift = max(4.0 * shift, 1e-8)

    def _diagonal(self) -> tuple[np.ndarray, np.ndarray]:
        """The assembled matrix's value array (a view) and the positions of its diagonal in it."""
        mat = self.form.mat
        if self._diag is None or self._diag[0] is not mat:
            _, cols, ptr = mat.CSR()
            cols, ptr = np.asarray(cols, dtype=np.int64), np.asarray(ptr, dtype=np.int64)
            rows = np.repeat(np.arange(len(ptr) - 1), np.diff(ptr))
            self._diag = (mat, np.flatnonzero(cols == rows))
        return mat.AsVector().FV().NumPy(), self._diag[1]

    def _factor_ngsolve(self) -> None:
        """NGSolve's inverse of the assembled matrix ("cholmod": its LDLᵀ), its analysis reused."""
        if self._inv is None or self._factorized is not self.form.mat:
            # a new matrix (symmetric storage on a refined mesh, energy_form): factorize it
            self._factorized = self.form.mat
            inverse = "sparsecholesky" if self.inverse_type == "cholmod" else self.inverse_type
            self._inv = self._factorized.Inverse(self.freedofs, inverse=inverse)
        else:
            self._inv.Update()

    def _factor_llt(self) -> bool:
        """CHOLMOD's LLᵀ of the assembled matrix's free block; False: not positive definite (then the LDLᵀ)."""
        mat = self.form.mat
        if self._llt is None or self._llt.mat is not mat:
            self._llt = _FreeCholesky(mat, self.freedofs)
        ok = self._llt.factor()
        if not ok:
            self.counts["factorizations_ldlt"] += 1
        return ok

    def _inverse_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """Out = A⁻¹ r on the free dofs (0 elsewhere), A the factorized matrix."""
        if self._use_llt:
            assert self._llt is not None
            self._llt.solve_into(r, out)
        else:
            assert self._inv is not None, "factorize first"
            out.data = self._inv * r

    def solve_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """Out = J⁻¹ r (free dofs), condensation handled; r is overwritten."""
        t0 = time.perf_counter()
        a = self.form
        if self.condensed:
            r.data += a.harmonic_extension_trans * r
            self._inverse_into(r, out)
            out.data += a.harmonic_extension * out
            out.data += a.inner_solve * r
        else:
            self._inverse_into(r, out)
        self.timers["solve_s"] += time.perf_counter() - t0
        self.counts["solves"] += 1

    def extend(self, vec: ngs.BaseVector) -> None:
        """Add the condensed local dofs that follow the coupling dofs of ``vec`` (harmonic extension)."""
        if self.condensed:
            vec.data += self.form.harmonic_extension * vec

    def free_matrix(self) -> tuple[sps.csr_matrix, np.ndarray]:
        """The free block of the Newton matrix as a full symmetric scipy matrix, and the free dofs."""
        import scipy.sparse as sps  # a run needs it only for a stability diagnosis

        vals, cols, ptr = self.form.mat.CSR()
        n = self.form.mat.height
        A = sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(n, n))
        if sps.triu(A, 1).nnz == 0:  # symmetric storage keeps the lower triangle only
            A = A + sps.tril(A, -1).T
        fd = np.flatnonzero(np.array(list(self.freedofs), dtype=bool))
        return A[fd][:, fd], fd


class _FreeCholesky:
    """CHOLMOD's LLᵀ (:class:`ngbet.cholmod.CholmodFactor`) of the free block of an NGSolve matrix.

    The free-free entries are picked from the matrix's value array (CSR order; the lower triangle
    with symmetric storage) by positions found once for its pattern.
    """

    def __init__(self, mat: ngs.BaseMatrix, freedofs: ngs.BitArray) -> None:
        from ..cholmod import CholmodFactor, free_pattern

        self.mat = mat
        _, cols, ptr = mat.CSR()
        free = np.array(list(freedofs), dtype=bool)
        self.free = np.flatnonzero(free)
        self._sel, rows, fcols = free_pattern(np.asarray(ptr), np.asarray(cols), free)
        self._vals = mat.AsVector().FV().NumPy()
        self._factor = CholmodFactor(rows, fcols, len(self.free))

    def factor(self) -> bool:
        """Factorize the matrix's current values; False: not positive definite."""
        return self._factor.factor(self._vals[self._sel])

    def solve_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """Out = A⁻¹ r on the free dofs, 0 on the others."""
        x = np.zeros(len(out))
        x[self.free] = self._factor.solve(r.FV().NumPy()[self.free])
        out.FV().NumPy()[:] = x
