"""The continuum's linear algebra: the Newton matrix, its condensation, factorization and solves.

:class:`NewtonLinearSolver` owns what is numerics, not formulation: whether element-local dofs (Λ)
are condensed out before factorizing, the sparse inverse, the augmented Newton matrix of the exact
Lagrange method, and the time and count of every assembly, factorization and solve.

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
from typing import TYPE_CHECKING

import ngsolve as ngs
import numpy as np

from .compiled import add_energy

if TYPE_CHECKING:
    import scipy.sparse as sps

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
    the serial one to round-off (the order of the sparse adds). Measured at load 0.8 on 2 cores:
    assembly and factorization each 1.8–1.9x faster on two threads (9.5k and 53k dofs).
    """
    token = _ASSEMBLY_THREADS.set(n)
    try:
        yield
    finally:
        _ASSEMBLY_THREADS.reset(token)


def assembly_thread_count() -> int:
    """NGSolve threads of a linearization (assembly, factorization): :func:`assembly_threads` or the surrounding."""
    return _ASSEMBLY_THREADS.get() or ngs.GetNumThreads()


def pick_inverse(choice: str, indefinite: bool) -> str:
    """The sparse inverse of ``solver.linear_solver``.

    "auto": sparse LDLᵀ needs no zero pivots, fine for the condensed or minimization matrices,
    not for the uncondensed saddle point (zero Λ-Λ block), which gets UMFPACK.
    """
    if choice != "auto":
        return choice
    return "umfpack" if indefinite else "sparsecholesky"


def energy_form(X: ngs.FESpace, inverse: str, condense: bool) -> ngs.BilinearForm:
    """An empty symmetric form on ``X`` whose matrix ``inverse`` can factorize.

    NGSolve stores a symmetric form's matrix in full unless asked; for the sparse LDLᵀ
    ("sparsecholesky"), which reads the lower triangle only, the form stores just that: half
    the sparse adds of each assembly and half the memory (measured, native, one thread, load
    0.5: 9 495 dofs 10.1 → 8.9 ms, 63 267 dofs 111 → 94 ms per linearization). UMFPACK gets the full matrix
    (given the lower triangle of the uncondensed saddle point it reports it singular), and so
    does a mesh with levels (refined): there NGSolve's symmetric storage allocates a new matrix
    at each assembly until it holds one per level, each to be factorized anew.
    """
    lower = inverse == "sparsecholesky" and X.mesh.levels == 1
    return ngs.BilinearForm(X, symmetric=True, symmetric_storage=lower, condense=condense)


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
        energy (in parts, as :func:`ngbet.continuum.compiled.add_energy` takes it) whose Hessian
        serves as the condensed Newton matrix.
    K_ref : float
        The stiffness that scales K_aug [Pa].
    dx : ngsolve measure
        The integration measure of the energy.
    compile_mode : str
        How the augmented integrand is compiled (:func:`ngbet.continuum.compiled.compile_energy`):
        the mode the energy got, so that "auto" does not mix.
    """

    def __init__(self, form: ngs.BilinearForm, condense: bool, choice: str,
                 saddle_energy: Callable[[float], Sequence[ngs.CoefficientFunction]] | None = None,
                 K_ref: float = 1.0,
                 dx: object = None, compile_mode: str = "interpret") -> None:
        X = form.space
        self.K_aug = 0.0
        self.inverse_type = pick_inverse(choice, saddle_energy is not None and not condense)
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
        self.timers = {"assembly_s": 0.0, "factorization_s": 0.0, "solve_s": 0.0}
        self.counts = {"factorizations": 0, "solves": 0}

    @property
    def mat(self) -> ngs.BaseMatrix:
        """The assembled Newton matrix (condensed: the Schur complement on the coupling dofs)."""
        return self.form.mat

    def factorize(self, state: ngs.BaseVector) -> None:
        """Linearize at ``state`` and factorize (the symbolic factorization is reused)."""
        threaded = ngs.TaskManager() if _ASSEMBLY_THREADS.get() > 1 else contextlib.nullcontext()
        with threaded:  # assembly and factorization: two long parallel regions
            t0 = time.perf_counter()
            self.form.AssembleLinearization(state)
            t1 = time.perf_counter()
            if self._inv is None or self._factorized is not self.form.mat:
                # a new matrix (symmetric storage on a refined mesh, energy_form): factorize it
                self._factorized = self.form.mat
                self._inv = self._factorized.Inverse(self.freedofs, inverse=self.inverse_type)
            else:
                self._inv.Update()
        self.timers["assembly_s"] += t1 - t0
        self.timers["factorization_s"] += time.perf_counter() - t1
        self.counts["factorizations"] += 1

    def solve_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """Out = J⁻¹ r (free dofs), condensation handled; r is overwritten."""
        assert self._inv is not None, "factorize first"
        t0 = time.perf_counter()
        a = self.form
        if self.condensed:
            r.data += a.harmonic_extension_trans * r
            out.data = self._inv * r
            out.data += a.harmonic_extension * out
            out.data += a.inner_solve * r
        else:
            out.data = self._inv * r
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
