"""solver.compile: the choice between interpreted and native code, its fallbacks and its cache."""

import logging
import os
import subprocess
import sys

import ngsolve as ngs
import numpy as np
import pytest

from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics import compiled
from ngbet.runner.settings import continuum_solver
from ngbet.scene.document import default_scene

HAS_COMPILER = compiled._compiler() is not None


def _cf() -> ngs.CoefficientFunction:
    mesh = ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=0.5))
    u = ngs.H1(mesh, order=1).TrialFunction()
    return u * u + ngs.sqrt(1 + ngs.Grad(u) * ngs.Grad(u))


def test_auto_interprets_below_the_size_where_native_code_pays():
    _, mode = compiled.compile_energy(_cf(), "auto", compiled.NATIVE_IF_CACHED - 1)
    assert mode == "interpret"


def test_native_without_a_compiler_interprets_and_says_so(monkeypatch, caplog):
    monkeypatch.setattr(compiled, "_compiler", lambda: None)
    with caplog.at_level(logging.WARNING, logger="ngbet.numerics.compiled"):
        _, mode = compiled.compile_energy(_cf(), "native", 10)
    assert mode == "interpret"
    assert "no C++ compiler" in caplog.text


@pytest.mark.skipif(not HAS_COMPILER, reason="needs a C++ compiler and NGSolve's ngscxx")
def test_auto_compiles_nothing_when_the_cache_is_empty(monkeypatch, tmp_path):
    """From NATIVE_IF_CACHED dofs "auto" takes native code from the cache only: an empty cache
    interprets (the caching ngscxx refuses to compile), and leaves no object file."""
    monkeypatch.setenv("NGBET_CACHE_DIR", str(tmp_path))
    _, mode = compiled.compile_energy(_cf(), "auto", compiled.NATIVE_IF_CACHED)
    assert mode == "interpret"
    assert list((tmp_path / "native" / "objects").iterdir()) == []
    assert len(list((tmp_path / "native" / "bin").glob("*/ngscxx"))) == 1


LEAVES = """
import sys, ngsolve as ngs
from ngbet.numerics import compiled
from ngbet.watch import end_run_process
mesh = ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=0.5))
u = ngs.H1(mesh, order=1).TrialFunction()
cf = u * u + ngs.sqrt(1 + ngs.Grad(u) * ngs.Grad(u))
print(compiled.compile_energy(cf, sys.argv[1], compiled.NATIVE_IF_CACHED)[1], flush=True)
if sys.argv[2] == "as a run ends":
    end_run_process(0)
"""


def _left_behind(tmp_path, mode: str, ending: str) -> tuple[str, list[str]]:
    """Compile in a process of its own whose temporary directory is empty: (the mode used, what is left there)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir(exist_ok=True)
    env = {**os.environ, "TMPDIR": str(tmp), "NGBET_CACHE_DIR": str(tmp_path / "cache")}
    argv = [sys.executable, "-c", LEAVES, mode, ending]
    p = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip(), sorted(x.name for x in tmp.iterdir())


@pytest.mark.skipif(not HAS_COMPILER, reason="needs a C++ compiler and NGSolve's ngscxx")
@pytest.mark.parametrize("ending", ["as a run ends", "at the interpreter's exit"])
def test_a_compilation_that_fails_leaves_no_folder_behind(tmp_path, ending):
    """NGSolve leaves the folder of a failed compilation (here: "auto" with an empty cache) in the
    temporary directory, and a run's process (ended by os._exit) every folder: the compilations go to a
    folder of ngbet's that is removed when they are done."""
    assert _left_behind(tmp_path, "auto", ending) == ("interpret", [])


@pytest.mark.slow
@pytest.mark.skipif(not HAS_COMPILER, reason="needs a C++ compiler and NGSolve's ngscxx")
def test_native_code_leaves_no_folder_behind_when_a_run_ends(tmp_path):
    """A native compilation (cold, then from the cache) in a process that ends as a run's does."""
    for _ in range(2):
        assert _left_behind(tmp_path, "native", "as a run ends") == ("native", [])


def test_the_interpreted_linearization_is_the_hessian():
    """Symbolic derivatives (the interpreted default) give the tangent of the residual: a central
    difference of the residual agrees to the difference's own error (~1e-10)."""
    pr = continuum_solver(
        ContinuumProblem(
            default_scene().with_changes(
                **{
                    "discretization.mesh_size_mm": 20.0,
                    "discretization.corner_mesh_size_mm": 0.0,
                    "solver.compile": "interpret",
                }
            )
        )
    )
    assert pr.compile_mode == "interpret"
    pr.state.set_load(0.02)
    rng = np.random.default_rng(0)
    free = pr.problem.free_all
    pr.x[free] += 1e-4 * rng.standard_normal(int(free.sum()))
    pr.a.AssembleLinearization(pr.problem.gf.vec)
    v = pr.problem.gf.vec.CreateVector()
    v.FV().NumPy()[:] = rng.standard_normal(len(v)) * free
    Jv = v.CreateVector()
    Jv.data = pr.a.mat * v
    x0, eps = pr.x.copy(), 1e-7
    pr.x[:] = x0 + eps * v.FV().NumPy()
    rp = pr.residual()
    pr.x[:] = x0 - eps * v.FV().NumPy()
    rm = pr.residual()
    fd = (rp - rm) / (2 * eps)
    assert np.linalg.norm(Jv.FV().NumPy() - fd) < 1e-8 * np.linalg.norm(fd)


def _state(h_mm: float, mode: str) -> ContinuumSolver:
    pr = continuum_solver(
        ContinuumProblem(
            default_scene().with_changes(
                **{
                    "discretization.mesh_size_mm": h_mm,
                    "discretization.corner_mesh_size_mm": 0.0,
                    "solver.compile": mode,
                }
            )
        )
    )
    assert pr.compile_mode == mode
    pr.state.set_load(0.02)
    free = pr.problem.free_all
    pr.x[free] += 1e-4 * np.random.default_rng(0).standard_normal(int(free.sum()))
    return pr


def _matrices(pr: ContinuumSolver) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The energy's uncondensed Hessian, the condensed Newton matrix and the residual."""
    pr.a.AssembleLinearization(pr.problem.gf.vec)
    pr.linear.form.AssembleLinearization(pr.problem.gf.vec)
    return np.array(pr.a.mat.CSR()[0]), np.array(pr.linear.mat.AsVector()), pr.residual()


@pytest.mark.slow
@pytest.mark.skipif(not HAS_COMPILER, reason="needs a C++ compiler and NGSolve's ngscxx")
def test_native_code_gives_the_interpreted_tangent(monkeypatch, tmp_path):
    """A cold native compile (the integrand, then its first derivatives for the Newton matrix:
    about a minute), then the same tangent and residual to round-off: the energy's uncondensed
    Hessian (automatic differentiation of the compiled integrand) and the condensed Newton
    matrix (symbolic first derivatives, compiled). Two meshes in one process share the cached
    code (the same source) and each keeps its own objects: the second is compared, then the first."""
    monkeypatch.setenv("NGBET_CACHE_DIR", str(tmp_path))
    first, second = _state(20.0, "native"), _state(25.0, "native")
    for h, native in ((25.0, second), (20.0, first)):
        (A0, N0, r0), (A1, N1, r1) = _matrices(_state(h, "interpret")), _matrices(native)
        assert np.abs(A1 - A0).max() < 1e-13 * np.abs(A0).max()
        assert np.abs(N1 - N0).max() < 1e-14 * np.abs(N0).max()
        assert np.abs(r1 - r0).max() < 1e-14 * np.abs(r0).max()
    objects = tmp_path / "native" / "objects"
    assert len(list(objects.glob("*.o"))) >= 6  # the integrands and their derivatives
    assert len(list(objects.glob("*.so"))) == len(list(objects.glob("*.o")))  # each code object linked once


@pytest.mark.slow
@pytest.mark.skipif(not HAS_COMPILER, reason="needs a C++ compiler and NGSolve's ngscxx")
def test_without_ld_the_library_is_linked_whole(monkeypatch, tmp_path):
    """The caching ngsld falls back to NGSolve's plain link when no ``ld`` is found: the energy
    of the native integrand is the interpreted one's, and no library is cached."""
    monkeypatch.setenv("NGBET_CACHE_DIR", str(tmp_path))
    which = compiled.shutil.which
    monkeypatch.setattr(compiled.shutil, "which", lambda name: None if name == "ld" else which(name))
    fes = ngs.H1(ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=0.5)), order=1)
    u = fes.TrialFunction()
    cf = u * u + ngs.sqrt(1 + ngs.Grad(u) * ngs.Grad(u))
    native, mode = compiled.compile_energy(cf, "native", 10)
    assert mode == "native"
    g = ngs.GridFunction(fes)
    g.Set(ngs.x * ngs.y)
    energies = []
    for c in (cf.Compile(), native):
        form = ngs.BilinearForm(fes)
        form += ngs.Variation(c * ngs.dx)
        energies.append(form.Energy(g.vec))
    # ∫ (xy)² + sqrt(1 + y² + x²) over the unit square, up to the P1 interpolant of xy
    assert 1.3 < energies[0] < 1.5  # 1.3919 for the exact xy
    assert energies[1] == pytest.approx(energies[0], rel=1e-14)
    objects = tmp_path / "native" / "objects"
    assert list(objects.glob("*.o")) and not list(objects.glob("*.so"))
