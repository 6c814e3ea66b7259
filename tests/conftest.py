"""Shared test helpers, and the test tiers.

Three tiers: the default run (``python -m pytest``) holds the unit and finite-element tests, fast;
``-m integration`` the whole commands, studies, fault injection, builds, the hard cases and a few
long finite-element checks (marked here: INTEGRATION_MODULES whole, LONG_CHECKS; other tests mark
themselves); ``-m slow`` the long runs. ``-m "integration or slow"`` with the default gives everything.
"""

import numpy as np
import pytest

from ngbet.scene.document import Scene

#: modules that run whole commands, studies, worker processes and the hard cases
INTEGRATION_MODULES = {
    "test_command.py",
    "test_faults.py",
    "test_hard_cases.py",
    "test_studies.py",
    "test_study_workers.py",
}
#: long finite-element checks of other modules (15-40 s each on the 2-core machine at load 6,
#: together more than a third of the default tier): with the integration tier
LONG_CHECKS = {
    ("test_cholmod.py", "test_the_llt_solves_as_the_ldlt"),
    ("test_cholmod.py", "test_a_matrix_that_is_not_positive_definite_goes_to_the_ldlt"),
    ("test_discrete_symmetry.py", "test_stability_check_of_the_network_reports_both_blocks"),
    # processes stopped by signals, and paths a faster test of their module covers too (2-5 s each):
    # with them the default tier took 2 min 54 s on 2 cores at load 1, against the 3 minutes it may
    ("test_fit_parallel.py", "test_a_stopped_fit_leaves_no_worker_behind"),
    ("test_fit_faults.py", "test_a_fit_stuck_in_one_library_call_records_its_interruption"),
    ("test_barrier_patch.py", "test_after_the_corner_closes_each_increment_takes_one_or_two_linearizations"),
    ("test_continuum.py", "test_ideal_kinematics_energy_is_approached_from_below"),
    ("test_cholmod.py", "test_the_default_scene_keeps_its_forces_with_the_llt"),
    ("test_discrete_symmetry.py", "test_path_with_cholmod_is_the_path_with_the_ldlt"),
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in INTEGRATION_MODULES or (item.path.name, item.originalname) in LONG_CHECKS:
            item.add_marker(pytest.mark.integration)


def _listing(folder):
    """Every path under ``folder`` with its size and modification time (what a test could have written)."""
    from pathlib import Path

    root = Path(folder)
    return {
        str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in root.rglob("*")
        if p.is_file()
        and ".git" not in p.parts
        and "__pycache__" not in p.parts
        and ".pytest_cache" not in p.parts
        and not p.name.endswith(".pyc")
    }


@pytest.fixture(scope="session", autouse=True)
def the_working_folder_is_left_as_it_was():
    """The folder pytest was started in holds the same files, unchanged, after the session.

    A command's default folders (out/run, out/studies/NAME, the study cache out/studies/cache)
    are relative to the working folder: a test that forgot its --out would write into the
    checkout. Checked for the out/ folder of the starting folder (the rest of a checkout is the
    code under test, which an editor may touch while the tests run).
    """
    import os
    from pathlib import Path

    out = Path(os.getcwd()) / "out"
    before = _listing(out) if out.is_dir() else {}
    yield
    after = _listing(out) if out.is_dir() else {}
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"the tests wrote into {out}: {changed[:10]}"


@pytest.fixture(autouse=True)
def in_a_folder_of_its_own(tmp_path_factory, monkeypatch):
    """Every test runs in an empty working folder of its own: default output folders land there, not in ./out."""
    monkeypatch.chdir(tmp_path_factory.mktemp("cwd"))


def coarse(**changes) -> Scene:
    """The paper's scene on a coarse mesh (10 mm, p = 2): seconds, not minutes."""
    base = {
        "discretization.mesh_size_mm": 10.0,
        "discretization.corner_mesh_size_mm": 0.0,
        "discretization.order_u": 2,
        "outputs.vtk": False,
        "outputs.plot": False,
    }
    base.update(changes)
    return Scene().with_changes(**base)


@pytest.fixture
def coarse_scene():
    return coarse


def carry(problem, target, first_step, settings, *, psi=None, hessian=None, watch=None, locate=None, **path):
    """The load path of ``problem`` to ``target`` carried to its end, its steps kept: the PathResult.

    ``path`` holds the other fields of the path settings; ``hessian``, ``watch`` and ``locate``
    the problem's capabilities (:func:`ngbet.numerics.path.load_steps`).
    """
    from ngbet.numerics.engine import Steps
    from ngbet.numerics.path import load_steps
    from ngbet.numerics.settings import PathSettings

    path.update({k: tuple(path[k]) for k in ("stops", "chord_at") if k in path})
    steps = Steps(
        load_steps(
            problem,
            PathSettings(target=target, first_step=first_step, **path),
            settings,
            psi=psi,
            hessian=hessian,
            watch=watch,
            locate=locate,
        )
    )
    for _ in steps:
        pass
    return steps.result


def capabilities(solver):
    """What a continuum solver can do beyond the Problem protocol, as ``ngbet run`` hands it to the path."""
    return {"hessian": solver if solver.can_relax else None, "watch": solver.problem, "locate": solver.problem}


class OneDofToy:
    """The linear algebra of a one-dof toy problem x = (λ, y) with λ the Dirichlet entry and the
    tangent J = dr_y/dy, as the continuation engines see a problem; subclasses give the residual,
    the energy and ``factorize`` (which sets J)."""

    J: float
    x: np.ndarray
    dirichlet = np.array([True, False])
    weights = np.array([0.0, 1.0])

    @property
    def lam(self):
        return float(self.x[0])

    @property
    def state(self):
        return self

    def solve(self, r):
        return np.array([0.0, -r[1] / self.J])

    def load_tangent(self, dlam):
        return np.array([dlam, dlam / self.J])

    def clamp_predictor(self, dlam):
        return np.array([dlam, 0.0])

    def norm(self, dx):
        return abs(dx[1])

    def load_derivative(self, psi, tangent):
        return float(psi @ np.array([-tangent[1], self.J * tangent[1] - tangent[0]]))

    def converged(self):
        pass


class Fold(OneDofToy):
    """A one-dof toy with a snap-back in the control λ: E = G(y) − λ y, r_y = g(y) − λ with
    g(y) = y³ − 1.5 y² + 0.6 y, which rises to a fold at y₁ = (3 − √1.8)/6 (λ = g(y₁) = 0.0726),
    falls to λ = 0.0274 at y₂ = (3 + √1.8)/6 and rises again (so the path passes λ = 0.05 three
    times). x = (λ, y): λ is the Dirichlet entry."""

    def __init__(self):
        self.x = np.zeros(2)

    @staticmethod
    def g(y):
        return y**3 - 1.5 * y**2 + 0.6 * y

    def set_load(self, lam):
        self.x[0] = lam

    def residual(self):
        y = self.x[1]
        return np.array([-y, self.g(y) - self.x[0]])

    def energy(self):
        y = self.x[1]
        return y**4 / 4 - y**3 / 2 + 0.3 * y**2 - self.x[0] * y

    def factorize(self):
        y = self.x[1]
        self.J = 3 * y**2 - 3 * y + 0.6


class DoubleWell(OneDofToy):
    """A one-dof toy of a snap-through under displacement control: x = (λ, y), λ the Dirichlet entry,
    E = y⁴/4 − y²/2 − λy, so r_y = y³ − y − λ and the reaction r_λ = −y. From the left well
    (y = −1 at λ = 0) the branch y < −1/√3 folds at λ_f = 2/(3√3) = 0.3849; beyond it the only
    equilibrium is in the right well, where y = 2/√3 at λ_f: a jump that releases
    E(−1/√3) − E(2/√3) = 1/12 + 2/3 = 0.75 at λ_f."""

    inadmissible_hint = ""

    def __init__(self, y0: float = -1.0) -> None:
        self.x = np.array([0.0, y0])

    def set_load(self, lam):
        self.x[0] = lam

    def residual(self):
        lam, y = self.x
        return np.array([-y, y**3 - y - lam])

    def energy(self):
        lam, y = self.x
        return y**4 / 4 - y**2 / 2 - lam * y

    def factorize(self, shift=0.0):
        J = 3 * self.x[1] ** 2 - 1
        while shift > 0 and J + shift * abs(J) <= 0:  # raised until positive definite
            shift = max(4 * shift, 1e-8)
        self.J = J + shift * abs(J)
        return shift

    def lowest_mode(self):
        J = 3 * self.x[1] ** 2 - 1
        return J / max(abs(J), 1e-300), np.array([0.0, 1.0])

    def merit(self, r):
        return self.energy()

    def admissible(self):
        return ""

    def begin_relaxation(self):
        pass


@pytest.fixture
def made_problems(monkeypatch):
    """Every ContinuumProblem built while the test runs, in order; each keeps the last state solved."""
    from ngbet.continuum import problem as problem_module

    made = []
    init = problem_module.ContinuumProblem.__init__

    def keep(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(problem_module.ContinuumProblem, "__init__", keep)
    return made
