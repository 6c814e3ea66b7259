"""The scene: the one description of a simulation.

A scene is a frozen dataclass made of small frozen sections::

    Scene
    ├── model            "continuum" (constrained micromorphic) or "discrete" (yarn network)
    ├── specimen         geometry of the rectangular BET specimen, yarn angle   [mm, deg]
    ├── material         K_el, K_sh [Pa], alpha1, alpha2 [Pa m^2]  (paper, Table 1)
    ├── effects          which energy terms and fields are built, constraint method
    ├── discretization   mesh size [mm], polynomial order of each field
    ├── loading          final clamp displacement u0 [mm], first step [mm]
    ├── solver           numerics only: tolerances, step control, linear solver
    ├── outputs          which observables and files are produced
    └── discrete         parameters of the discrete model (paper, Table 2)

Every section validates itself on construction and raises :class:`SceneError` naming the key,
the value and the reason, so that a bad scene is refused before anything is meshed. Scenes are
read from and written to TOML; the embedded default is the paper's specimen and Table 1, loaded
to u0 = 56 mm. Variants come from :func:`dataclasses.replace` or :meth:`Scene.with_changes`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import tomli_w


class SceneError(ValueError):
    """A scene value is missing, unknown or out of range; the message names the key."""


def _check(cond: bool, key: str, value: Any, why: str) -> None:
    if not cond:
        raise SceneError(f"scene key '{key}' = {value!r}: {why}")


def _positive(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0,
               f"{section}.{n}", v, "must be a finite number > 0")


def _nonnegative(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
               f"{section}.{n}", v, "must be a finite number >= 0")


def _boolean(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, bool), f"{section}.{n}", v, "must be true or false")


def _integer(section: str, obj: Any, name: str, lo: int, hi: int) -> None:
    v = getattr(obj, name)
    _check(isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi,
           f"{section}.{name}", v, f"must be an integer from {lo} to {hi}")


AUTO = "auto"


def _auto_or(section: str, obj: Any, name: str, check: Any, what: str, old: tuple[Any, ...]) -> None:
    """``"auto"`` or a value passing ``check``; the former numeric sentinels ``old`` get a clear error."""
    v = getattr(obj, name)
    if v == AUTO:
        return
    if not isinstance(v, bool) and v in old:
        raise SceneError(f"scene key '{section}.{name}' = {v!r}: for the automatic value write "
                         f"{name} = \"auto\"; otherwise give {what}")
    _check(not isinstance(v, (bool, str)) and check(v), f"{section}.{name}", v, f"must be \"auto\" or {what}")


def _choice(section: str, obj: Any, name: str, choices: tuple[str, ...]) -> None:
    v = getattr(obj, name)
    _check(v in choices, f"{section}.{name}" if section else name, v, f"must be one of {', '.join(map(repr, choices))}")


#: the largest specimen dimension accepted [mm]: forces and sizes of larger ones overflow (1e308 did)
MAX_SPECIMEN_MM = 1e6


@dataclass(frozen=True)
class Specimen:
    """Rectangular BET specimen B = [0, L] x [0, W]; clamps on X = 0 (fixed) and X = L (moving).

    The thick yarns (bending stiffness alpha1) run along m1 = (cos a, sin a), the thin yarns
    (alpha2) along m2 = (-cos a, sin a), with a = ``yarn_angle_deg`` (45 in the paper).
    """

    length_mm: float = 220.0  # L, loading direction e1
    width_mm: float = 70.0  # W
    thickness_mm: float = 15.0  # t: converts forces per unit thickness [N/m] to machine forces [N]
    yarn_angle_deg: float = 45.0  # angle of the thick yarns m1 to e1
    name: str = "madeo2016-70x220"

    def __post_init__(self) -> None:
        _positive("specimen", self, "length_mm", "width_mm", "thickness_mm")
        for n in ("length_mm", "width_mm", "thickness_mm"):
            _check(getattr(self, n) <= MAX_SPECIMEN_MM, f"specimen.{n}", getattr(self, n),
                   f"must be at most {MAX_SPECIMEN_MM:g} mm (1 km): larger values overflow the computation")
        a = self.yarn_angle_deg
        _check(isinstance(a, (int, float)) and 5.0 <= a <= 85.0, "specimen.yarn_angle_deg", a,
               "must lie between 5 and 85 degrees")
        _check(self.zone_a_length_mm > 0, "specimen.width_mm", self.width_mm,
               f"the central zone A vanishes: a BET specimen needs L > W/tan(a) "
               f"(L = {self.length_mm} mm, W/tan(a) = {self.width_mm / math.tan(math.radians(a)):.1f} mm)")

    # SI views ---------------------------------------------------------------------------------
    @property
    def L(self) -> float:
        """Length [m]."""
        return self.length_mm * 1e-3

    @property
    def W(self) -> float:
        """Width [m]."""
        return self.width_mm * 1e-3

    @property
    def t(self) -> float:
        """Thickness [m]."""
        return self.thickness_mm * 1e-3

    @property
    def m1(self) -> tuple[float, float]:
        """Direction of the thick yarns (cos a, sin a)."""
        a = math.radians(self.yarn_angle_deg)
        return (math.cos(a), math.sin(a))

    @property
    def m2(self) -> tuple[float, float]:
        """Direction of the thin yarns (−cos a, sin a)."""
        a = math.radians(self.yarn_angle_deg)
        return (-math.cos(a), math.sin(a))

    @property
    def cos0(self) -> float:
        """m1·m2 = −cos 2a: the cosine of the rest angle between the yarn directions (0 at ±45°)."""
        return -math.cos(2 * math.radians(self.yarn_angle_deg))

    # ideal BET kinematics -----------------------------------------------------------------------
    @property
    def zone_a_length_mm(self) -> float:
        """D = L - W/tan(a): length of the central zone A along the axis (150 mm in the paper)."""
        return self.length_mm - self.width_mm / math.tan(math.radians(self.yarn_angle_deg))

    @property
    def locking_u0_mm(self) -> float:
        """Clamp displacement at which inextensible yarns lock: D (1/cos a - 1) (62.1 mm in the paper)."""
        return self.zone_a_length_mm * (1.0 / math.cos(math.radians(self.yarn_angle_deg)) - 1.0)


@dataclass(frozen=True)
class Material:
    """Constitutive parameters of the constrained micromorphic continuum (paper, Table 1)."""

    K_el: float = 0.7e6  # Pa: equivalent elongation (decrimping and slip) of both yarn families
    K_sh: float = 21e3  # Pa: in-plane shear (angle variation i8)
    alpha1: float = 2e3  # Pa m^2: bending of the thick yarns (along m1)
    alpha2: float = 20.0  # Pa m^2: bending of the thin yarns (along m2)
    # coefficients of the stiffening shear laws (effects.shear_law; ngbet.continuum.physics)
    K_sh4: float = 0.0  # Pa: "polynomial", 1/4 K_sh4 i8^4
    K_sh6: float = 0.0  # Pa: "polynomial", 1/6 K_sh6 i8^6
    K_lock: float = 0.0  # Pa: "locking", modulus of the term that diverges at the locking angle
    gamma_lock_deg: float = 60.0  # deg: "locking", shear angle at which the yarns lock
    # "table": the rises [Pa] of the shear stress between consecutive control points of a cubic
    # B-spline in |i8| (uniform knots from 0 to shear_table_i8_max; the stress is 0 at i8 = 0); each
    # rise >= 0, so the stress is monotone and the energy convex (ngbet.continuum.physics)
    shear_stress_steps_Pa: tuple[float, ...] = ()
    shear_table_i8_max: float = 1.0  # "table": |i8| of the last knot; beyond it the stress goes on linearly
    # deg: effects.jamming, the acute angle between the deformed yarns below which they jam (the
    # barrier K_jam s_jam^2 (1 - t)^3 / t, t = sin(angle) / sin(jamming_angle_deg), K_jam = max(K_el, K_sh);
    # ngbet.continuum.physics.jamming_energy)
    jamming_angle_deg: float = 5.0

    def __post_init__(self) -> None:
        _nonnegative("material", self, "K_el", "K_sh", "alpha1", "alpha2", "K_sh4", "K_sh6", "K_lock")
        g = self.gamma_lock_deg
        _check(isinstance(g, (int, float)) and not isinstance(g, bool) and 0 < g < 90, "material.gamma_lock_deg",
               g, "must lie strictly between 0 and 90 degrees")
        j = self.jamming_angle_deg
        _check(isinstance(j, (int, float)) and not isinstance(j, bool) and 0 < j < 90, "material.jamming_angle_deg",
               j, "must lie strictly between 0 and 90 degrees")
        steps = self.shear_stress_steps_Pa
        _check(isinstance(steps, (list, tuple)), "material.shear_stress_steps_Pa", steps, "must be a list of numbers")
        object.__setattr__(self, "shear_stress_steps_Pa", tuple(steps))
        for v in self.shear_stress_steps_Pa:
            _check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
                   "material.shear_stress_steps_Pa", v, "each rise must be a finite number >= 0 (a monotone table)")
        _check(len(self.shear_stress_steps_Pa) <= 40, "material.shear_stress_steps_Pa", len(steps),
               "at most 40 control points")
        _positive("material", self, "shear_table_i8_max")

    def internal_lengths_mm(self) -> tuple[float, float]:
        """l_i = sqrt(alpha_i / K_sh) [mm]: 309 mm and 31 mm for Table 1."""
        if self.K_sh == 0:
            return (math.inf, math.inf)
        return tuple(1e3 * math.sqrt(a / self.K_sh) for a in (self.alpha1, self.alpha2))  # type: ignore[return-value]


CONSTRAINTS = ("lagrange", "penalty")
PENALTY_FORMS = ("mixed", "full")
SHEAR_LAWS = ("quadratic", "polynomial", "locking", "table")  # ngbet.continuum.physics.SHEAR_LAWS


@dataclass(frozen=True)
class Effects:
    """The physical effects a scene calls for; only their energy terms and fields are built.

    ``bending`` brings the micro-variable phi (H1) and the constraint phi = i8, imposed either by
    a Lagrange multiplier Lambda in L2 (``constraint = "lagrange"``) or by the penalty
    1/2 K (phi - i8)^2 (``"penalty"``, paper appendix A). ``penalty_form = "mixed"`` writes the
    penalty with Lambda as an element-local unknown (Lambda (phi - i8) - Lambda^2 / 2K) that is
    condensed out: it converges to the Lagrange solution like 1/K on the same mesh; ``"full"`` is
    the paper's pointwise penalty, solved in its exactly equivalent mixed form (Lambda of the degree
    of phi - i8, on which the L2 projection is the identity: the same discrete solution, far fewer
    Newton steps at large K; see ngbet.continuum.problem). The formulation is chosen here alone:
    ``solver.condense`` only eliminates element-local unknowns before factorizing. ``jamming``
    keeps the yarns from crossing: a barrier on the sine of the angle between the deformed yarns,
    zero above ``material.jamming_angle_deg`` (on by default; no ordinary state reaches it).
    """

    shear: bool = True  # 1/2 K_sh i8^2
    # the shear energy: "quadratic" 1/2 K_sh i8^2 (the paper's); "polynomial" adds 1/4 K_sh4 i8^4
    # + 1/6 K_sh6 i8^6; "locking" adds a term that diverges at material.gamma_lock_deg (K_lock);
    # "table": a monotone spline of the shear stress against |i8| (material.shear_stress_steps_Pa)
    shear_law: str = "quadratic"
    elongation: bool = True  # 1/2 K_el [(sqrt(i4) - 1)^2 + (sqrt(i6) - 1)^2]
    bending: bool = True  # 1/2 alpha1 phi_1^2 + 1/2 alpha2 phi_2^2 with phi = i8
    constraint: str = "lagrange"
    penalty_K: float = 1e8  # Pa, used only with constraint = "penalty"
    penalty_form: str = "mixed"
    # Pa; adds ½ K_s (φ − i8)² to the Lagrange and mixed-penalty forms (an augmented Lagrangian:
    # zero with its variation wherever φ = i8, so the exact solution is unchanged). It acts on the
    # within-element part of φ − i8 that Λ ∈ L2(p − 2) leaves free. "auto" (default): element by
    # element K_s = 0.1 min(alpha1, alpha2) / h_T^2, a tenth of the bending energy the exact
    # constraint would charge for a variation of i8 on the element's scale; 0: off; > 0: that
    # constant (ngbet.continuum.problem)
    stabilization_K: float | str = AUTO
    # the yarns cannot cross: a barrier on the sine of the angle between the deformed yarns, zero
    # while they are more open than material.jamming_angle_deg and growing without bound as they
    # close (docs/model.md, *Jamming*); no ordinary state reaches it. false: off
    jamming: bool = True

    def __post_init__(self) -> None:
        _boolean("effects", self, "shear", "elongation", "bending", "jamming")
        _choice("effects", self, "constraint", CONSTRAINTS)
        _choice("effects", self, "penalty_form", PENALTY_FORMS)
        _choice("effects", self, "shear_law", SHEAR_LAWS)
        _check(self.shear or self.shear_law == "quadratic", "effects.shear_law", self.shear_law,
               "a shear law needs effects.shear = true")
        _auto_or("effects", self, "stabilization_K",
                 lambda v: isinstance(v, (int, float)) and math.isfinite(v) and v >= 0,
                 "a number >= 0 [Pa] (0: off); \"auto\" is K_s = 0.1 min(alpha1, alpha2) / h_T^2", old=(-1,))
        _positive("effects", self, "penalty_K")
        _check(self.elongation, "effects.elongation", self.elongation,
               "the yarn elongation term is what makes the yarns resist stretching; without it the "
               "tangent is singular (inextensible yarns would need a constraint ngbet does not model)")
        _check(self.shear or self.bending, "effects.shear", self.shear,
               "with neither shear nor bending nothing resists the shear of the yarn network")

    @property
    def fields(self) -> tuple[str, ...]:
        """Names of the unknown fields this scene needs, in the order of the compound space."""
        if not self.bending:
            return ("u",)
        if self.constraint == "lagrange" or self.penalty_form == "mixed":
            return ("u", "phi", "lam")
        return ("u", "phi")


#: the highest polynomial order a scene may ask for: the reference at 37 mm uses p = 14 (135 873
#: dofs on its split-corner mesh); the memory check before meshing refuses what this machine cannot hold
MAX_ORDER = 16


@dataclass(frozen=True)
class Discretization:
    """Mesh and polynomial orders (``order_phi = "auto"``: order_u; ``order_lam = "auto"``: the stable pair).

    The defaults are the accurate default discretization (:data:`DEFAULT_DISCRETIZATION`): a 10 mm
    mesh graded to 0.25 mm at the four clamp corners, p = 3.
    """

    mesh_size_mm: float = 10.0
    order_u: int = 3
    order_phi: int | str = AUTO  # "auto": same as order_u
    order_lam: int | str = AUTO  # "auto": max(order_u - 2, 0), the stable pair (see ngbet.continuum.problem)
    quad_bonus: int = 0  # extra quadrature order for the non-polynomial sqrt(i4), sqrt(i6) terms
    structured: bool = False  # crossed structured mesh instead of Netgen's unstructured one
    # mesh size at the four corners where a clamp meets a free edge (singular points of the
    # solution); 0: no local refinement. Netgen grades the mesh from there to mesh_size_mm. The
    # default 0.25 gives way (to 0, with a note) when the scene sets a mesh finer than it or a
    # structured mesh without setting this key
    corner_mesh_size_mm: float = 0.25
    # times the elements at the four clamp corners are bisected after meshing (each bisection
    # halves the element at a corner). Netgen leaves one triangle spanning each 90-degree corner,
    # two of whose edges lie on the boundary; one bisection splits it, which at the same order
    # lowers the force error several-fold (docs/accuracy.md). 0: the mesh as Netgen makes it.
    corner_bisections: int = 0
    # relative error of the force at the final load that the run must reach; 0: take the
    # discretization as given. > 0: ngbet chooses mesh, grading and order (ngbet.continuum.estimate)
    target_error: float = 0.0

    def __post_init__(self) -> None:
        _positive("discretization", self, "mesh_size_mm")
        _integer("discretization", self, "order_u", 1, MAX_ORDER)
        _auto_or("discretization", self, "order_phi", lambda v: isinstance(v, int) and 1 <= v <= MAX_ORDER,
                 f"an integer from 1 to {MAX_ORDER}", old=(0,))
        _auto_or("discretization", self, "order_lam", lambda v: isinstance(v, int) and 0 <= v <= MAX_ORDER - 1,
                 f"an integer from 0 to {MAX_ORDER - 1}", old=(-1,))
        _integer("discretization", self, "quad_bonus", 0, 10)
        _boolean("discretization", self, "structured")
        _nonnegative("discretization", self, "corner_mesh_size_mm")
        _integer("discretization", self, "corner_bisections", 0, 10)
        _check(isinstance(self.target_error, (int, float)) and not isinstance(self.target_error, bool)
               and (self.target_error == 0 or 1e-6 <= self.target_error < 1), "discretization.target_error",
               self.target_error, "must be 0 (off) or a relative error from 1e-6 to below 1")
        _check(self.corner_mesh_size_mm <= self.mesh_size_mm, "discretization.corner_mesh_size_mm",
               self.corner_mesh_size_mm, "must not exceed discretization.mesh_size_mm")
        _check(not (self.structured and self.corner_mesh_size_mm > 0), "discretization.corner_mesh_size_mm",
               self.corner_mesh_size_mm, "a structured mesh cannot be graded (set structured = false)")

    @property
    def p_u(self) -> int:
        """The order of u."""
        return self.order_u

    @property
    def p_phi(self) -> int:
        """The order of phi."""
        return self.order_u if self.order_phi == AUTO else int(self.order_phi)

    @property
    def p_lam(self) -> int:
        """The order of the multiplier."""
        return max(self.order_u - 2, 0) if self.order_lam == AUTO else int(self.order_lam)


PAPER_STOPS_MM = (37.0,)


@dataclass(frozen=True)
class Loading:
    """Clamp displacement u0 of X = L along e1, applied in steps."""

    u0_mm: float = 56.0
    # loads a step must land on (shapes at 37 mm in the paper); a stop beyond u0_mm is refused,
    # except the default one, which applies only when u0_mm passes it
    stops_mm: tuple[float, ...] = (37.0,)
    # the continuum's path is smooth: 16 mm, then 37 (stop), then 56 mm in 3 steps and 7 Newton
    # iterations; the discrete model has its own limits ([discrete])
    first_step_mm: float = 16.0
    max_step_mm: float = 28.0
    min_step_mm: float = 0.05
    # a results.csv row at least every this many mm: the path lands on every multiple of it (and
    # on the stops), so that results.csv is a force-displacement curve; 0: only where the step
    # control lands
    output_every_mm: float = 2.0

    def __post_init__(self) -> None:
        _positive("loading", self, "u0_mm", "first_step_mm", "max_step_mm", "min_step_mm")
        _nonnegative("loading", self, "output_every_mm")
        object.__setattr__(self, "stops_mm", tuple(self.stops_mm))
        for s in self.stops_mm:
            _check(isinstance(s, (int, float)) and not isinstance(s, bool) and s > 0, "loading.stops_mm", s,
                   "each stop must be a number > 0")
            # the default stop (the paper's shape station) applies only when u0 passes it
            _check(s <= self.u0_mm or self.stops_mm == PAPER_STOPS_MM, "loading.stops_mm", s,
                   f"a stop beyond the final load loading.u0_mm = {self.u0_mm:g} mm would never be reached")
        _check(self.min_step_mm <= self.first_step_mm, "loading.min_step_mm", self.min_step_mm,
               "must not exceed loading.first_step_mm")
        _check(self.min_step_mm <= self.max_step_mm, "loading.min_step_mm", self.min_step_mm,
               "must not exceed loading.max_step_mm")

    @property
    def path_stops_mm(self) -> tuple[float, ...]:
        """The loads the path lands on below u0_mm [mm]: the stops and the multiples of output_every_mm."""
        grid: tuple[float, ...] = ()
        if self.output_every_mm > 0:
            n = int(math.floor(self.u0_mm / self.output_every_mm * (1 + 1e-12)))
            grid = tuple(round(k * self.output_every_mm, 9) for k in range(1, n + 1))
        return tuple(sorted({s for s in (*self.stops_mm, *grid) if s < self.u0_mm - 1e-9}))


LINEAR_SOLVERS = ("auto", "cholmod", "sparsecholesky", "umfpack", "pardiso")


@dataclass(frozen=True)
class Solver:
    """Numerics only (kept apart from the problem).

    Newton stops when the Newton decrement |<du, r>|, an energy, is below ``rtol`` times the
    current total energy (unit-free), or below ``atol_energy`` J/m.
    """

    rtol: float = 1e-10
    atol_energy: float = 1e-14  # J/m: floor for states with vanishing energy
    max_iterations: int = 12
    grow_after: int = 4  # grow the step when Newton needed at most this many iterations
    growth: float = 1.5
    cut: float = 0.5
    # "auto": CHOLMOD's LL^T where cvxopt is installed (ngbet[cholmod]; a matrix that is not
    # positive definite goes to the sparse LDL^T), else the sparse LDL^T ("sparsecholesky");
    # UMFPACK for the continuum's uncondensed saddle point
    linear_solver: str = "auto"
    # eliminate element-local dofs (Lambda) before factorizing; false keeps them in the factorized
    # matrix (slower): a numerics choice, the same discrete solution for every formulation
    condense: bool = True
    # NGSolve threads; "auto": continuum on one thread with each assembly on the idle cores,
    # discrete on all cores (ngbet.run.thread_policy). One by default: on the 2-core machines
    # measured, two threads were slower in wall time (solves and residuals wait for a core)
    threads: int | str = 1
    predictor: str = "tangent"  # "tangent" (Euler) or "clamp" (u += du0 X/L)
    # continuum: "displacement" control; "arclength": pseudo-arclength continuation in (state, u0)
    # from the start; "auto": displacement control, arc length where it fails (through a snap-back)
    path_following: str = "displacement"
    # the energy integrand: "interpret", "native" (C++, object files cached across runs), "auto": by
    # size (interpreted below 30 000 dofs, cached native code above, compiled from 500 000 dofs)
    compile: str = "auto"
    # continuum, arc length: at a bifurcation "stay" on the branch followed or "switch" to the
    # bifurcated one along its critical mode (recorded in summary.json)
    branch: str = "stay"

    def __post_init__(self) -> None:
        _positive("solver", self, "rtol", "atol_energy", "growth")
        _integer("solver", self, "max_iterations", 1, 1000)
        _integer("solver", self, "grow_after", 0, 1000)
        _auto_or("solver", self, "threads", lambda v: isinstance(v, int) and 1 <= v <= 1024,
                 "an integer from 1 to 1024", old=(0,))
        _check(0 < self.cut < 1, "solver.cut", self.cut, "must lie strictly between 0 and 1")
        _check(self.growth >= 1, "solver.growth", self.growth, "must be >= 1")
        _choice("solver", self, "linear_solver", LINEAR_SOLVERS)
        _choice("solver", self, "predictor", ("tangent", "clamp"))
        _choice("solver", self, "path_following", ("displacement", "arclength", "auto"))
        _choice("solver", self, "compile", ("auto", "interpret", "native"))
        _choice("solver", self, "branch", ("stay", "switch"))
        _check(self.branch == "stay" or self.path_following != "displacement", "solver.branch", self.branch,
               "needs solver.path_following = 'arclength' or 'auto' (displacement control stays on its branch)")
        _check(self.branch == "stay" or self.condense, "solver.branch", self.branch,
               "needs solver.condense = true (the uncondensed saddle-point tangent has no stability test, so no "
               "critical mode to switch along)")
        _boolean("solver", self, "condense")


FIELD_OUTPUTS = ("shear_angle", "constraint", "elongation")


@dataclass(frozen=True)
class Outputs:
    """What is computed and written; what is not asked for is not computed."""

    reaction: bool = True  # force [N/m] and [N] by the volume-integral method
    double_force: bool = True  # needs bending
    energy: bool = True
    profile: bool = True  # mid-axis (Y = W/2) vertical displacement
    profile_points: int = 111
    fields: tuple[str, ...] = FIELD_OUTPUTS
    vtk: bool = True  # final fields for ParaView
    vtk_every_step: bool = False
    # discretization error of the force and profile (ngbet.continuum.estimate): "stops" (at the
    # load stops and the final load), "every" (every converged step), "final", or "off"
    error_estimate: str = "stops"
    plot: bool = True

    def __post_init__(self) -> None:
        _boolean("outputs", self, "reaction", "double_force", "energy", "profile", "vtk",
                 "vtk_every_step", "plot")
        _integer("outputs", self, "profile_points", 3, 100000)
        _choice("outputs", self, "error_estimate", ("stops", "every", "final", "off"))
        object.__setattr__(self, "fields", tuple(self.fields))
        for f in self.fields:
            _check(f in FIELD_OUTPUTS, "outputs.fields", f, f"unknown field, known: {', '.join(FIELD_OUTPUTS)}")


@dataclass(frozen=True)
class Discrete:
    """Parameters of the discrete model (paper section 3, Table 2); the spacing is ours."""

    EA1: float = 50000.0  # N: axial stiffness of the thick yarns
    EA2: float = 50000.0  # N: thin yarns
    EI1: float = 0.4  # N m^2: bending stiffness of the thick yarns
    EI2: float = 1e-3  # N m^2: thin yarns
    K_phi: float = 2.5e-4  # N m: rotational spring at each crossing
    K_slip: float = 11.0  # N/m: translational slip spring at each crossing
    K_inter: float = 11.0  # N: trusses between adjacent yarns of the same family
    spacing_mm: float = 5.0  # distance between neighbouring yarns of one family (not in the paper)
    elements_per_segment: int = 1  # beam elements between two crossings
    inter_layout: str = "neighbours"  # "neighbours" or "none"
    # yarn ends on a clamp: "free" = pinned (position prescribed, rotation free: the discrete
    # counterpart of the continuum's clamp, which prescribes u, not the yarn rotation); "held" =
    # built in (rotation held too). The choice decides the sense of the S-shape: see docs/discrete.md.
    end_rotation: str = "free"
    # load steps of the discrete model (the network snaps; it needs shorter steps than the continuum)
    first_step_mm: float = 2.0
    max_step_mm: float = 8.0

    def __post_init__(self) -> None:
        _positive("discrete", self, "EA1", "EA2", "spacing_mm")
        _nonnegative("discrete", self, "EI1", "EI2", "K_phi", "K_slip", "K_inter")
        _integer("discrete", self, "elements_per_segment", 1, 64)
        _choice("discrete", self, "inter_layout", ("neighbours", "none"))
        _choice("discrete", self, "end_rotation", ("free", "held"))
        _positive("discrete", self, "first_step_mm", "max_step_mm")


@dataclass(frozen=True)
class Calibration:
    """What ``ngbet fit`` adjusts when no ``--params`` are given, and the fabric's yarn families.

    The runs do not read this section; it travels with the scene so that a fabric's scene says
    which of its parameters the measured curves determine.
    """

    # material keys the fit adjusts (e.g. "material.K_el"); a list key such as
    # "material.shear_stress_steps_Pa" stands for each of its entries
    params: tuple[str, ...] = ()
    lower: tuple[float, ...] = ()  # bound below of each parameter (empty: start / 1e4); > 0
    upper: tuple[float, ...] = ()  # bound above of each parameter (empty: start x 1e4)
    yarns_m1: str = ""  # the yarn family along m1 (bending stiffness alpha1), e.g. "warp, 3.39 ends/cm"
    yarns_m2: str = ""  # the yarn family along m2 (alpha2)

    def __post_init__(self) -> None:
        for name in ("params", "lower", "upper"):
            v = getattr(self, name)
            _check(isinstance(v, (list, tuple)), f"calibration.{name}", v, "must be a list")
            object.__setattr__(self, name, tuple(v))
        known = {f.name for f in fields(Material)}
        for p in self.params:
            section, _, key = p.partition(".") if isinstance(p, str) else ("", "", "")
            _check(section == "material" and key in known, "calibration.params", p,
                   f"must name a material key (material.{', material.'.join(sorted(known))})")
        _check(len(set(self.params)) == len(self.params), "calibration.params", list(self.params),
               "names a key twice")
        for name in ("lower", "upper"):
            v = getattr(self, name)
            _check(len(v) in (0, len(self.params)), f"calibration.{name}", list(v),
                   f"needs one bound per entry of calibration.params ({len(self.params)}) or none")
            for b in v:
                _check(isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) and b > 0,
                       f"calibration.{name}", b, "each bound must be a finite number > 0 (the fit works on ln p)")
        if self.lower and self.upper:
            for p, lo, hi in zip(self.params, self.lower, self.upper, strict=True):
                _check(lo < hi, "calibration.lower", lo, f"must lie below calibration.upper ({hi}) for {p}")
        _check(isinstance(self.yarns_m1, str) and isinstance(self.yarns_m2, str), "calibration.yarns_m1",
               self.yarns_m1, "must be text")


MODELS = ("continuum", "discrete")

#: what each model does not read: whole sections (None) or some of their keys. A non-default value
#: there is reported by name (:meth:`Scene.unused_keys`, a :class:`SceneWarning` on construction).
NOT_READ_BY: dict[str, dict[str, tuple[str, ...] | None]] = {
    "continuum": {"discrete": None},
    "discrete": {"material": None, "effects": None, "discretization": None, "solver": ("condense",)},
}


class SceneWarning(UserWarning):
    """A scene value that has no effect on the chosen model."""


class SceneNote(UserWarning):
    """A default value that gave way to a key the scene sets (the note says which and why)."""


def _yield_defaults(data: dict[str, Any], explicit: set[str]) -> None:
    """Give defaults that contradict a key the scene sets way to it, in the tables ``data``, with a note.

    ``explicit``: the keys ("section.key") the scene sets. Nothing valid is refused because of a
    default the user never set: the graded corners (``discretization.corner_mesh_size_mm`` = 0.25
    by default) are switched off for a mesh finer than them or a structured mesh; the smallest
    load step (``loading.min_step_mm`` = 0.05) becomes the user's first or largest step where
    that is smaller.
    """
    d = data.get("discretization")
    key = "discretization.corner_mesh_size_mm"
    default = Discretization.corner_mesh_size_mm
    if isinstance(d, dict) and key not in explicit and d.get("corner_mesh_size_mm", default) == default:
        h, structured = d.get("mesh_size_mm", Discretization.mesh_size_mm), d.get("structured", False)
        finer = _number(h) and h < default
        if finer or structured is True:
            why = (f"discretization.mesh_size_mm = {h:g} is finer than the default corners" if finer
                   else "a structured mesh cannot be graded")
            d["corner_mesh_size_mm"] = 0.0
            warnings.warn(SceneNote(f"{key} = 0 (no corner grading) instead of the default {default:g}: {why}"),
                          stacklevel=4)
    ld = data.get("loading")
    key = "loading.min_step_mm"
    default = Loading.min_step_mm
    if isinstance(ld, dict) and key not in explicit and ld.get("min_step_mm", default) == default:
        steps = [ld.get(k, getattr(Loading, k)) for k in ("first_step_mm", "max_step_mm")]
        smallest = min((v for v in steps if _number(v) and v > 0), default=default)
        if smallest < default:
            ld["min_step_mm"] = smallest
            warnings.warn(SceneNote(f"{key} = {smallest:g} instead of the default {default:g}: the scene's "
                                    "load steps are smaller"), stacklevel=4)


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_SECTIONS: dict[str, type] = {
    "specimen": Specimen,
    "material": Material,
    "effects": Effects,
    "discretization": Discretization,
    "loading": Loading,
    "solver": Solver,
    "outputs": Outputs,
    "discrete": Discrete,
    "calibration": Calibration,
}


@dataclass(frozen=True)
class Scene:
    """A complete, validated simulation description."""

    model: str = "continuum"
    specimen: Specimen = field(default_factory=Specimen)
    material: Material = field(default_factory=Material)
    effects: Effects = field(default_factory=Effects)
    discretization: Discretization = field(default_factory=Discretization)
    loading: Loading = field(default_factory=Loading)
    solver: Solver = field(default_factory=Solver)
    outputs: Outputs = field(default_factory=Outputs)
    discrete: Discrete = field(default_factory=Discrete)
    calibration: Calibration = field(default_factory=Calibration)

    def __post_init__(self) -> None:
        _choice("", self, "model", MODELS)
        for name, cls in _SECTIONS.items():
            _check(isinstance(getattr(self, name), cls), name, getattr(self, name), f"must be a {cls.__name__}")
        # loads past ideal yarn locking are valid: the yarns are extensible (K_el), and the run
        # warns (locking_warning); ideal locking belongs to inextensible yarns
        _check(self.discretization.target_error == 0 or self.outputs.reaction, "discretization.target_error",
               self.discretization.target_error, "is an accuracy of the clamp force: it needs outputs.reaction = true")
        if self.model == "discrete":
            _check(self.solver.branch == "stay", "solver.branch", self.solver.branch,
                   "branch switching is for the continuum model (the discrete model follows the load)")
            n = yarns_per_family(self.specimen, self.discrete.spacing_mm)
            _check(n >= MIN_YARNS_PER_FAMILY, "discrete.spacing_mm", self.discrete.spacing_mm,
                   f"leaves about {n} yarns per family across the {self.specimen.length_mm:g} x "
                   f"{self.specimen.width_mm:g} mm specimen; a yarn network needs at least "
                   f"{MIN_YARNS_PER_FAMILY} (spacing <= {_max_spacing(self.specimen):.3g} mm)")
        if self.model == "continuum":
            _check(self.solver.linear_solver != "cholmod" or self.solver.condense, "solver.linear_solver",
                   self.solver.linear_solver, "needs solver.condense = true: the uncondensed Newton matrix holds "
                   "the multiplier's block and is indefinite, which a Cholesky LL^T cannot factorize")
            m, e = self.material, self.effects
            if e.shear and e.shear_law == "table":
                _check(len(m.shear_stress_steps_Pa) >= 2 and sum(m.shear_stress_steps_Pa) > 0,
                       "material.shear_stress_steps_Pa", list(m.shear_stress_steps_Pa),
                       "effects.shear_law = 'table' needs at least 2 rises, not all 0")
            elif e.shear:
                _check(m.K_sh > 0, "material.K_sh", m.K_sh, "must be > 0 when effects.shear is on")
            _check(m.K_el > 0, "material.K_el", m.K_el, "must be > 0 (effects.elongation is on)")
            rest = min(2 * self.specimen.yarn_angle_deg, 180 - 2 * self.specimen.yarn_angle_deg)
            _check(not e.jamming or m.jamming_angle_deg < rest, "material.jamming_angle_deg", m.jamming_angle_deg,
                   f"must be below the angle between the yarns at rest ({rest:g} degrees), else they jam at rest")
            if e.bending:
                _check(m.alpha1 + m.alpha2 > 0, "material.alpha1", m.alpha1,
                       "alpha1 + alpha2 must be > 0 when effects.bending is on (else turn bending off)")
                for fam, a in ((1, m.alpha1), (2, m.alpha2)):
                    _check(a > 0, f"material.alpha{fam}", a,
                           f"must be > 0 when effects.bending is on: without bending stiffness the yarns of family "
                           f"{fam} lose ellipticity where they are compressed, and the model has no mesh-independent "
                           "solution there (a small value, e.g. 1e-3 Pa m^2, keeps it well posed; or turn bending off)")
                _check(self.discretization.p_lam < self.discretization.p_phi or e.fields == ("u", "phi"),
                       "discretization.order_lam", self.discretization.order_lam,
                       "the multiplier order must be below the order of phi, else the constraint locks")

        unused = self.unused_keys()
        if unused:
            warnings.warn(SceneWarning(f"model = {self.model!r} does not read {', '.join(unused)}: "
                                       "these values have no effect"), stacklevel=3)

    def unused_keys(self) -> list[str]:
        """The keys with a non-default value that the scene's model does not read ("section.key")."""
        out = []
        for name, keys in NOT_READ_BY[self.model].items():
            section, default = getattr(self, name), _SECTIONS[name]()
            for f in fields(section):
                value = getattr(section, f.name)
                if (keys is None or f.name in keys) and value != getattr(default, f.name):
                    out.append(f"{name}.{f.name}")
        return out

    # construction ------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict[str, Any], explicit: set[str] | None = None) -> Scene:
        """Build a scene from nested dicts (TOML tables); unknown keys are refused by name.

        Missing sections and keys take the defaults (the same as :func:`default_scene`'s). A
        default that contradicts a key the scene sets gives way to it with a :class:`SceneNote`
        (``explicit``: the keys "section.key" set by the user; default: those in ``data``).
        """
        if not isinstance(data, dict):
            raise SceneError(f"a scene must be a table of sections, got {type(data).__name__}")
        if explicit is None:
            explicit = {f"{n}.{k}" for n, t in data.items() if isinstance(t, dict) for k in t}
        data = {n: dict(t) if isinstance(t, dict) else t for n, t in data.items()}
        _yield_defaults(data, explicit)
        known = {"model", *_SECTIONS}
        for key in data:
            if key not in known:
                raise SceneError(f"unknown scene section '{key}'; known: {', '.join(sorted(known))}")
        kwargs: dict[str, Any] = {}
        if "model" in data:
            kwargs["model"] = data["model"]
        for name, scls in _SECTIONS.items():
            if name not in data:
                continue
            table = data[name]
            if not isinstance(table, dict):
                raise SceneError(f"scene section '{name}' must be a table, got {table!r}")
            names = {f.name for f in fields(scls)}
            for key in table:
                if key not in names:
                    raise SceneError(f"unknown scene key '{name}.{key}'; known in [{name}]: {', '.join(sorted(names))}")
            try:
                kwargs[name] = scls(**table)
            except TypeError as exc:  # pragma: no cover - names are checked above
                raise SceneError(f"scene section '{name}': {exc}") from None
        return cls(**kwargs)

    @classmethod
    def from_toml(cls, path: str | Path) -> Scene:
        """Read a scene file; missing sections and keys take the default values."""
        return cls.from_dict(read_toml(path))

    @classmethod
    def from_toml_string(cls, text: str) -> Scene:
        """Read a scene from TOML text."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SceneError(f"scene is not valid TOML: {exc}") from None
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """Nested dicts of plain values (the TOML tables)."""
        d = dataclasses.asdict(self)
        d["outputs"]["fields"] = list(d["outputs"]["fields"])
        d["loading"]["stops_mm"] = list(d["loading"]["stops_mm"])
        d["material"]["shear_stress_steps_Pa"] = list(d["material"]["shear_stress_steps_Pa"])
        for k in ("params", "lower", "upper"):
            d["calibration"][k] = list(d["calibration"][k])
        return d

    def to_toml(self) -> str:
        """The complete scene as TOML text."""
        return tomli_w.dumps(self.to_dict())

    def with_changes(self, **dotted: Any) -> Scene:
        """A variant: ``scene.with_changes(**{"material.alpha1": 20.0, "loading.u0_mm": 37})``.

        A default of this scene that contradicts a changed key gives way to it (:class:`SceneNote`).
        """
        return Scene.from_dict(apply_changes(self.to_dict(), dotted), explicit=set(dotted))

    def digest(self) -> str:
        """A stable hash of the complete scene (for caches)."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]


def read_toml(path: str | Path) -> dict[str, Any]:
    """The tables of a scene file; :class:`SceneError` naming the file when it cannot be read as TOML."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"scene file not found: {path}") from None
    except IsADirectoryError:
        raise SceneError(f"scene file {path} is a directory, not a TOML file") from None
    except OSError as exc:
        raise SceneError(f"scene file {path} cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise SceneError(f"scene file {path} is not a text (UTF-8) file: is it a TOML scene?") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file {path} is not valid TOML: {exc}") from None


def apply_changes(data: dict[str, Any], dotted: dict[str, Any]) -> dict[str, Any]:
    """The tables ``data`` with ``{"section.key": value}`` (or ``{"model": ...}``) set; a new dict."""
    d = {n: dict(t) if isinstance(t, dict) else t for n, t in data.items()}
    for key, value in dotted.items():
        section, _, name = key.partition(".")
        if not name:
            d[section] = value
            continue
        if section not in _SECTIONS:
            raise SceneError(f"unknown scene section '{section}' in '{key}'")
        table = d.setdefault(section, {})
        if not isinstance(table, dict):
            raise SceneError(f"scene section '{section}' must be a table, got {table!r}")
        table[name] = value
    return d


MIN_YARNS_PER_FAMILY = 4


def yarns_per_family(specimen: Specimen, spacing_mm: float) -> int:
    """Yarns of one family across the specimen at a spacing [mm].

    The width of the rectangle across the yarns, L sin a + W cos a, over the spacing (the larger family count at
    a != 45 deg is not needed: both families use the smaller of the two widths).
    """
    a = math.radians(specimen.yarn_angle_deg)
    across = min(specimen.length_mm * math.sin(a) + specimen.width_mm * math.cos(a),
                 specimen.length_mm * math.cos(a) + specimen.width_mm * math.sin(a))
    return int(across // spacing_mm)


def _max_spacing(specimen: Specimen) -> float:
    return yarns_per_family(specimen, 1.0) / MIN_YARNS_PER_FAMILY


#: The default discretization (:class:`Discretization`'s defaults): the cheapest setting measured
#: within 0.3 % of the reference force at 56 mm (107.2365 N, ngbet.studies.reference) and within 1 % on the mid-axis
#: profile: 10 mm mesh graded to 0.25 mm at the four clamp corners, p = 3 (0.13 % and 0.39 %; its
#: solve takes 0.4–0.6 times that of the uniform 5 mm p = 2 mesh, which is 2.1 % and 7.8 % off,
#: measured interleaved on a loaded 2-core machine). p = 2 on the same mesh is 0.16 % on the force
#: but 4 % on the profile.
DEFAULT_DISCRETIZATION: dict[str, Any] = {k: getattr(Discretization, k)
                                           for k in ("mesh_size_mm", "corner_mesh_size_mm", "order_u")}


def default_scene() -> Scene:
    """The paper's bias extension test: 70 x 220 mm, Table 1, Lagrange multiplier, u0 to 56 mm.

    On the accurate default discretization (:data:`DEFAULT_DISCRETIZATION`). The same scene as
    ``Scene()``: a scene file's missing keys take these values.
    """
    return Scene()
