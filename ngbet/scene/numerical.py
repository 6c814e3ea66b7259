"""The numerical sections of a scene: discretization, loading, solver, outputs, the discrete model, calibration.

Each is a frozen dataclass that validates itself on construction (:mod:`ngbet.scene.validate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from .physical import Material
from .validate import AUTO, auto_or, boolean, check, choice, integer, nonnegative, positive

__all__ = [
    "CHOSEN_BY_TARGET",
    "FIELD_OUTPUTS",
    "FIGURE_FORMATS",
    "LINEAR_SOLVERS",
    "MAX_ORDER",
    "PAPER_STOPS_MM",
    "Calibration",
    "Discrete",
    "Discretization",
    "Loading",
    "Outputs",
    "Solver",
]

#: the keys of :class:`Discretization` that the accuracy ladder sets on each of its settings when
#: ``target_error`` > 0 (:meth:`ngbet.runner.ladder.Rung.apply`): the scene's own values go unread
CHOSEN_BY_TARGET = (
    "mesh_size_mm",
    "order_u",
    "order_phi",
    "order_lam",
    "corner_mesh_size_mm",
    "corner_bisections",
    "structured",
)
#: the highest polynomial order a scene may ask for: the reference at 37 mm uses p = 14 (135 873
#: dofs on its split-corner mesh); the memory check before meshing refuses what this machine cannot hold
MAX_ORDER = 16


@dataclass(frozen=True, kw_only=True)
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
        positive("discretization", self, "mesh_size_mm")
        integer("discretization", self, "order_u", 1, MAX_ORDER)
        auto_or(
            "discretization",
            self,
            "order_phi",
            lambda v: isinstance(v, int) and 1 <= v <= MAX_ORDER,
            f"an integer from 1 to {MAX_ORDER}",
        )
        auto_or(
            "discretization",
            self,
            "order_lam",
            lambda v: isinstance(v, int) and 0 <= v <= MAX_ORDER - 1,
            f"an integer from 0 to {MAX_ORDER - 1}",
        )
        integer("discretization", self, "quad_bonus", 0, 10)
        boolean("discretization", self, "structured")
        nonnegative("discretization", self, "corner_mesh_size_mm")
        integer("discretization", self, "corner_bisections", 0, 10)
        check(
            isinstance(self.target_error, (int, float))
            and not isinstance(self.target_error, bool)
            and (self.target_error == 0 or 1e-6 <= self.target_error < 1),
            "discretization.target_error",
            self.target_error,
            "must be 0 (off) or a relative error from 1e-6 to below 1",
        )
        check(
            self.corner_mesh_size_mm <= self.mesh_size_mm,
            "discretization.corner_mesh_size_mm",
            self.corner_mesh_size_mm,
            "must not exceed discretization.mesh_size_mm",
        )
        check(
            not (self.structured and self.corner_mesh_size_mm > 0),
            "discretization.corner_mesh_size_mm",
            self.corner_mesh_size_mm,
            "a structured mesh cannot be graded (set structured = false)",
        )

    def chosen_by_target(self) -> list[str]:
        """The keys (``discretization.<key>``) set away from their defaults that ``target_error`` replaces.

        The accuracy ladder chooses mesh, grading and orders (:data:`CHOSEN_BY_TARGET`). Empty
        without a target.
        """
        if not self.target_error:
            return []
        default = Discretization()
        return [f"discretization.{k}" for k in CHOSEN_BY_TARGET if getattr(self, k) != getattr(default, k)]

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


@dataclass(frozen=True, kw_only=True)
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
        positive("loading", self, "u0_mm", "first_step_mm", "max_step_mm", "min_step_mm")
        nonnegative("loading", self, "output_every_mm")
        check(
            isinstance(self.stops_mm, (list, tuple)),
            "loading.stops_mm",
            self.stops_mm,
            "must be a list of loads [mm], e.g. [37] (on the command line: --set 'loading.stops_mm=[37]')",
        )
        object.__setattr__(self, "stops_mm", tuple(self.stops_mm))
        for s in self.stops_mm:
            check(
                isinstance(s, (int, float)) and not isinstance(s, bool) and s > 0,
                "loading.stops_mm",
                s,
                "each stop must be a number > 0",
            )
            # the default stop (the paper's shape station) applies only when u0 passes it
            check(
                s <= self.u0_mm or self.stops_mm == PAPER_STOPS_MM,
                "loading.stops_mm",
                s,
                f"a stop beyond the final load loading.u0_mm = {self.u0_mm:g} mm would never be reached: "
                "raise loading.u0_mm or leave the stop out (e.g. --set 'loading.stops_mm=[]')",
            )
        check(
            self.min_step_mm <= self.first_step_mm,
            "loading.min_step_mm",
            self.min_step_mm,
            "must not exceed loading.first_step_mm",
        )
        check(
            self.min_step_mm <= self.max_step_mm,
            "loading.min_step_mm",
            self.min_step_mm,
            "must not exceed loading.max_step_mm",
        )

    @property
    def path_stops_mm(self) -> tuple[float, ...]:
        """The loads the path lands on below u0_mm [mm]: the stops and the multiples of output_every_mm."""
        grid: tuple[float, ...] = ()
        if self.output_every_mm > 0:
            n = int(math.floor(self.u0_mm / self.output_every_mm * (1 + 1e-12)))
            grid = tuple(round(k * self.output_every_mm, 9) for k in range(1, n + 1))
        return tuple(sorted({s for s in (*self.stops_mm, *grid) if s < self.u0_mm - 1e-9}))


LINEAR_SOLVERS = ("auto", "cholmod", "sparsecholesky", "umfpack", "pardiso")


@dataclass(frozen=True, kw_only=True)
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
    # discrete on all cores (ngbet.runner.threads.thread_policy). One by default: on the 2-core machines
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
        positive("solver", self, "rtol", "atol_energy", "growth")
        integer("solver", self, "max_iterations", 1, 1000)
        integer("solver", self, "grow_after", 0, 1000)
        auto_or("solver", self, "threads", lambda v: isinstance(v, int) and 1 <= v <= 1024, "an integer from 1 to 1024")
        check(0 < self.cut < 1, "solver.cut", self.cut, "must lie strictly between 0 and 1")
        check(self.growth >= 1, "solver.growth", self.growth, "must be >= 1")
        choice("solver", self, "linear_solver", LINEAR_SOLVERS)
        choice("solver", self, "predictor", ("tangent", "clamp"))
        choice("solver", self, "path_following", ("displacement", "arclength", "auto"))
        choice("solver", self, "compile", ("auto", "interpret", "native"))
        choice("solver", self, "branch", ("stay", "switch"))
        check(
            self.branch == "stay" or self.path_following != "displacement",
            "solver.branch",
            self.branch,
            "needs solver.path_following = 'arclength' or 'auto' (displacement control stays on its branch)",
        )
        check(
            self.branch == "stay" or self.condense,
            "solver.branch",
            self.branch,
            "needs solver.condense = true (the uncondensed saddle-point tangent has no stability test, so no "
            "critical mode to switch along)",
        )
        boolean("solver", self, "condense")


FIELD_OUTPUTS = ("shear_angle", "constraint", "elongation")
FIGURE_FORMATS = ("png", "pdf", "svg")


@dataclass(frozen=True, kw_only=True)
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
    figure_formats: tuple[str, ...] = ("png",)  # files of each figure: any of "png", "pdf", "svg"

    def __post_init__(self) -> None:
        boolean("outputs", self, "reaction", "double_force", "energy", "profile", "vtk", "vtk_every_step", "plot")
        check(
            isinstance(self.figure_formats, (list, tuple)) and len(self.figure_formats) > 0,
            "outputs.figure_formats",
            self.figure_formats,
            'must be a non-empty list such as ["png", "pdf"]',
        )
        object.__setattr__(self, "figure_formats", tuple(self.figure_formats))
        for f in self.figure_formats:
            check(
                f in FIGURE_FORMATS,
                "outputs.figure_formats",
                f,
                f"unknown figure format, known: {', '.join(FIGURE_FORMATS)}",
            )
        check(
            len(set(self.figure_formats)) == len(self.figure_formats),
            "outputs.figure_formats",
            list(self.figure_formats),
            "names a format twice",
        )
        integer("outputs", self, "profile_points", 3, 100000)
        choice("outputs", self, "error_estimate", ("stops", "every", "final", "off"))
        check(
            isinstance(self.fields, (list, tuple)),
            "outputs.fields",
            self.fields,
            f'must be a list of field names, e.g. ["{FIELD_OUTPUTS[0]}"] (known: {", ".join(FIELD_OUTPUTS)})',
        )
        object.__setattr__(self, "fields", tuple(self.fields))
        for f in self.fields:
            check(f in FIELD_OUTPUTS, "outputs.fields", f, f"unknown field, known: {', '.join(FIELD_OUTPUTS)}")


@dataclass(frozen=True, kw_only=True)
class Discrete:
    """Parameters of the discrete model (paper section 3, Table 2); the spacing is ours."""

    EA1: float = 50000.0  # N: axial stiffness of the thick yarns
    EA2: float = 50000.0  # N: thin yarns
    EI1: float = 0.4  # N m^2: bending stiffness of the thick yarns (> 0: without it the network is a mechanism)
    EI2: float = 1e-3  # N m^2: thin yarns (> 0)
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
        positive("discrete", self, "EA1", "EA2", "spacing_mm")
        nonnegative("discrete", self, "K_phi", "K_slip", "K_inter")
        for key in ("EI1", "EI2"):
            check(
                getattr(self, key) > 0,
                f"discrete.{key}",
                getattr(self, key),
                "the yarns' bending stiffness ties the rotation at each crossing to its yarn; at 0 the crossing "
                "springs (K_phi) hold nothing and the network is a mechanism with a singular tangent: give it a "
                "value > 0 (the force tends to 0 with it)",
            )
        integer("discrete", self, "elements_per_segment", 1, 64)
        choice("discrete", self, "inter_layout", ("neighbours", "none"))
        choice("discrete", self, "end_rotation", ("free", "held"))
        positive("discrete", self, "first_step_mm", "max_step_mm")


@dataclass(frozen=True, kw_only=True)
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
    # standard deviation of the second difference of ln of consecutive fitted shear-table rises: a
    # smoothness prior that continues the rises' trend where the data do not reach (0: none)
    table_smoothness_sd: float = 0.0

    def __post_init__(self) -> None:
        for name in ("params", "lower", "upper"):
            v = getattr(self, name)
            check(isinstance(v, (list, tuple)), f"calibration.{name}", v, "must be a list")
            object.__setattr__(self, name, tuple(v))
        known = {f.name for f in fields(Material)}
        for p in self.params:
            section, _, key = p.partition(".") if isinstance(p, str) else ("", "", "")
            check(
                section == "material" and key in known,
                "calibration.params",
                p,
                f"must name a material key (material.{', material.'.join(sorted(known))})",
            )
        check(len(set(self.params)) == len(self.params), "calibration.params", list(self.params), "names a key twice")
        for name in ("lower", "upper"):
            v = getattr(self, name)
            check(
                len(v) in (0, len(self.params)),
                f"calibration.{name}",
                list(v),
                f"needs one bound per entry of calibration.params ({len(self.params)}) or none",
            )
            for b in v:
                check(
                    isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) and b > 0,
                    f"calibration.{name}",
                    b,
                    "each bound must be a finite number > 0 (the fit works on ln p)",
                )
        if self.lower and self.upper:
            for p, lo, hi in zip(self.params, self.lower, self.upper, strict=True):
                check(lo < hi, "calibration.lower", lo, f"must lie below calibration.upper ({hi}) for {p}")
        nonnegative("calibration", self, "table_smoothness_sd")
        check(
            isinstance(self.yarns_m1, str) and isinstance(self.yarns_m2, str),
            "calibration.yarns_m1",
            self.yarns_m1,
            "must be text",
        )
