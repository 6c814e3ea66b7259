"""The damped Newton and the continuation: derivatives, convergence and failure after a bounded number of attempts."""

import json
import math

import ngsolve as ngs
import numpy as np
import pytest
from conftest import capabilities, carry, coarse

from ngbet.continuum.problem import ContinuumProblem
from ngbet.errors import ConvergenceError
from ngbet.numerics.settings import NewtonSettings
from ngbet.run import run
from ngbet.runner.settings import continuum_solver, newton_settings
from ngbet.tables import read_rows


def _deformed_problem(**changes):
    """The solver of a coarse problem carried to u0 = 20 mm, then perturbed off equilibrium so that
    every term of the Hessian (also the multiplier's curvature term Λ·D²i8) is exercised."""
    scene = coarse(
        **{"discretization.mesh_size_mm": 20.0, "solver.condense": False, "solver.linear_solver": "umfpack", **changes}
    )
    solver = continuum_solver(ContinuumProblem(scene))
    with ngs.TaskManager():
        carry(solver, 0.02, 0.01, newton_settings(scene), **capabilities(solver))
    rng = np.random.default_rng(1)
    free = solver.problem.free_all
    scale = _field_scales(solver.problem)
    solver.x[free] += 0.05 * scale[free] * rng.standard_normal(int(free.sum()))
    return solver


def _field_scales(problem):
    """Typical size of each unknown: u ~ 1 mm, φ ~ 0.1, Λ ~ K_sh · 0.1."""
    s = np.zeros(problem.X.ndof)
    size = {"u": 1e-3, "phi": 0.1, "lam": 0.1 * problem.scene.material.K_sh}
    for i, name in enumerate(problem.field_names):
        rng = problem.X.Range(i)
        s[rng.start : rng.stop] = size[name]
    return s


@pytest.mark.parametrize(
    "changes",
    [
        {"effects.constraint": "penalty", "effects.penalty_form": "full", "effects.penalty_K": 1e6},
        {"effects.constraint": "penalty", "effects.penalty_form": "mixed", "effects.penalty_K": 1e6},
        {"effects.constraint": "lagrange"},
    ],
    ids=["penalty-full", "penalty-mixed", "lagrange"],
)
def test_jacobian_matches_finite_differences_of_the_residual(changes):
    """J v = (r(x + εv) − r(x − εv)) / 2ε + O(ε²) for random directions v, on every row
    (Dirichlet rows included). ``solver.a`` is the exact energy's form (for the Lagrange method
    the Newton matrix ``solver.linear.form`` is deliberately the augmented one; the exact Hessian is checked
    here). A wrong sign or a missing term (e.g. the Λ·D²i8 curvature) gives errors of O(1)."""
    problem = _deformed_problem(**changes)
    rng = np.random.default_rng(2)
    x0 = problem.x.copy()
    scale = _field_scales(problem.problem)
    vec = problem.problem.gf.vec
    with ngs.TaskManager():
        problem.a.AssembleLinearization(vec)
        vin, vout = vec.CreateVector(), vec.CreateVector()
        errors = []
        for _ in range(3):
            v = scale * rng.standard_normal(len(x0))
            vin.FV().NumPy()[:] = v
            vout.data = problem.a.mat * vin
            Jv = vout.FV().NumPy().copy()
            fd = {}
            for eps in (1e-4, 5e-5):
                problem.x[:] = x0 + eps * v
                rp = problem.residual()
                problem.x[:] = x0 - eps * v
                rm = problem.residual()
                fd[eps] = (rp - rm) / (2 * eps)
            problem.x[:] = x0
            err = np.linalg.norm(fd[5e-5] - Jv) / np.linalg.norm(Jv)
            # O(ε²) truncation: halving ε divides the error by ~4 unless it is at round-off already
            err_coarse = np.linalg.norm(fd[1e-4] - Jv) / np.linalg.norm(Jv)
            errors.append((err, err_coarse))
    for err, err_coarse in errors:
        assert err < 1e-6, errors
        assert err < 0.5 * err_coarse or err < 1e-9, errors


def test_lagrange_newton_matrix_is_the_augmented_one():
    """The condensed Newton matrix of the Lagrange method is the mixed penalty's with K_aug:
    it differs from the exact Hessian only through Λ²/2K_aug, so applied to a direction without Λ
    component the two agree to round-off, and on a Λ direction they differ by exactly M/K_aug
    (M the L2 mass matrix of Λ): the quasi-Newton is close to Newton and its limit is exact."""
    solver = _deformed_problem(**{"effects.constraint": "lagrange", "solver.condense": True})
    problem = solver.problem
    # condense=True with Λ: the Newton matrix is condensed, rebuild the uncondensed augmented form to compare
    from ngbet.continuum import physics

    scene = problem.scene
    X = problem.X
    u, phi, lam = X.TrialFunction()
    inv = physics.invariants(ngs.Grad(u), problem.m1, problem.m2)
    m = scene.material
    base = (
        physics.elongation_energy(inv.i4, inv.i6, m.K_el)
        + physics.shear_energy(inv.i8, m.K_sh)
        + physics.bending_energy(ngs.Grad(phi), problem.m1, problem.m2, m.alpha1, m.alpha2)
        + physics.penalty_constraint(phi, inv.i8, problem.K_s)
    )  # the default stabilization
    assert problem.K_s_range[0] > 0
    aug = ngs.BilinearForm(X, symmetric=True)
    aug += ngs.Variation((base + physics.mixed_penalty_constraint(phi, inv.i8, lam, solver.linear.K_aug)) * problem.dx)
    with ngs.TaskManager():
        solver.a.AssembleLinearization(problem.gf.vec)
        aug.AssembleLinearization(problem.gf.vec)
        rng = np.random.default_rng(3)
        vin, o1, o2 = (problem.gf.vec.CreateVector() for _ in range(3))
        v = _field_scales(problem) * rng.standard_normal(X.ndof)
        r_lam = X.Range(2)
        v_nolam = v.copy()
        v_nolam[r_lam.start : r_lam.stop] = 0
        vin.FV().NumPy()[:] = v_nolam
        o1.data = solver.a.mat * vin
        o2.data = aug.mat * vin
        a1, a2 = o1.FV().NumPy(), o2.FV().NumPy()
        assert np.linalg.norm(a1 - a2) < 1e-12 * np.linalg.norm(a1)
        v_lam = v - v_nolam
        vin.FV().NumPy()[:] = v_lam
        o1.data = solver.a.mat * vin
        o2.data = aug.mat * vin
        diff = o2.FV().NumPy() - o1.FV().NumPy()
        # −M v_Λ / K_aug: relative to the coupling term it is ~K_sh/K_aug = 1e-6, and non-zero
        rel = np.linalg.norm(diff) / np.linalg.norm(o1.FV().NumPy())
    assert 0 < rel < 1e-4


def test_newton_converges_quadratically_on_a_load_step():
    """Full Newton (penalty, exact Jacobian): the decrement at least squares-ish from one
    iteration to the next once in the contraction region (δ_k+1 ≤ C δ_k² with a small C)."""
    scene = coarse(
        **{
            "effects.constraint": "penalty",
            "effects.penalty_K": 1e6,
            "loading.u0_mm": 20.0,
            "discretization.mesh_size_mm": 20.0,
        }
    )
    problem = continuum_solver(ContinuumProblem(scene))
    settings = NewtonSettings(rtol=1e-14, atol=1e-20, max_iterations=12, simplified_theta=0.0)
    with ngs.TaskManager():
        res = carry(problem, 0.02, 0.02, settings, **capabilities(problem))
    h = res.steps[0].history
    assert len(h) >= 3
    # the decrement is an energy ~ |dx|², so quadratic convergence of dx means δ_k+1 ~ δ_k²/δ_0
    assert h[2] < 1e-3 * h[1] and h[1] < 1e-2 * h[0], h


def test_simplified_exit_saves_a_linearization_without_changing_the_answer():
    """The simplified-Newton exit ends a step with one linearization less and the same force."""
    scene = coarse(**{"loading.u0_mm": 37.0, "discretization.mesh_size_mm": 20.0})
    forces, facts = [], []
    for theta in (0.0, 0.5):
        problem = continuum_solver(ContinuumProblem(scene))
        s = NewtonSettings(rtol=scene.solver.rtol, atol=scene.solver.atol_energy, simplified_theta=theta)
        with ngs.TaskManager():
            res = carry(problem, 0.037, 0.008, s, max_step=0.014, stops=[0.037], **capabilities(problem))
            forces.append(float(problem.residual() @ problem.problem.psi_u.vec.FV().NumPy()))
        facts.append(problem.counts["factorizations"])
        assert len(res.steps) >= 3
    assert facts[1] <= facts[0] - 3  # at least one linearization saved per load step (≥ 3 steps)
    assert abs(forces[1] - forces[0]) < 1e-8 * abs(forces[0])


def test_running_out_of_newton_iterations_fails_after_two_attempts(tmp_path):
    """Two Newton iterations carry the first 4 mm but not the grown step after it (4 -> 36 mm, no
    Newton reaches 1e-10 from so far in two iterations), and the first cut (x 0.1) falls below
    min_step = 4 mm: the run stops with a ConvergenceError that names the last converged load
    (4 mm) and keeps every attempt's history; the converged step already on disk is intact."""
    scene = coarse(
        **{
            "solver.max_iterations": 2,
            "solver.growth": 8.0,
            "solver.cut": 0.1,
            "loading.first_step_mm": 4.0,
            "loading.min_step_mm": 4.0,
            "loading.max_step_mm": 56.0,
            "loading.stops_mm": [],
            "loading.output_every_mm": 0.0,
            "discretization.mesh_size_mm": 20.0,
        }
    )
    with pytest.raises(ConvergenceError) as info:
        run(scene, tmp_path / "run")
    err = info.value
    assert [a.converged for a in err.attempts] == [True, False]  # 0 -> 4 mm, 4 -> 36 mm; no third try
    assert math.isclose(err.last_converged_mm, 4.0, rel_tol=1e-12)
    failed = [a for a in err.attempts if not a.converged]
    assert failed and all(a.iterations <= 2 for a in err.attempts)
    assert all(a.history for a in failed)  # each attempt says what its decrement was
    assert f"last converged load: {err.last_converged_mm:.6g} mm" in str(err)
    rows = read_rows(tmp_path / "run" / "results.csv")
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "failed" and "last converged load" in summary["error"]
    assert len(rows) == 1 and math.isclose(rows[-1]["u0_mm"], 4.0, rel_tol=1e-9)
    assert 0 < rows[0]["force_N"] < 10  # N: 5.2 N at 4 mm on this mesh (small-strain range)
