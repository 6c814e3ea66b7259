"""The physical sections of a scene: the specimen, the material (paper, Table 1) and the effects.

Each is a frozen dataclass that validates itself on construction (:mod:`ngbet.scene.validate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .validate import AUTO, auto_or, boolean, check, choice, nonnegative, positive

__all__ = [
    "CONSTRAINTS",
    "MAX_SPECIMEN_MM",
    "PENALTY_FORMS",
    "SHEAR_LAWS",
    "SHEAR_LAW_KEYS",
    "law_leaves_unread",
    "load_symbol",
    "Effects",
    "Material",
    "Specimen",
]

#: the largest specimen dimension accepted [mm]: forces and sizes of larger ones overflow (1e308 did)
MAX_SPECIMEN_MM = 1e6


@dataclass(frozen=True, kw_only=True)
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
        check(
            isinstance(self.name, str),
            "specimen.name",
            self.name,
            'must be a text, e.g. "fabric-100x200" (on the command line in quotes: '
            f"--set 'specimen.name=\"{self.name}\"')",
        )
        positive("specimen", self, "length_mm", "width_mm", "thickness_mm")
        for n in ("length_mm", "width_mm", "thickness_mm"):
            check(
                getattr(self, n) <= MAX_SPECIMEN_MM,
                f"specimen.{n}",
                getattr(self, n),
                f"must be at most {MAX_SPECIMEN_MM:g} mm (1 km): larger values overflow the computation",
            )
        a = self.yarn_angle_deg
        check(
            isinstance(a, (int, float)) and 5.0 <= a <= 85.0,
            "specimen.yarn_angle_deg",
            a,
            "must lie between 5 and 85 degrees",
        )
        check(
            self.zone_a_length_mm > 0,
            "specimen.width_mm",
            self.width_mm,
            f"the central zone A vanishes: a BET specimen needs L > W/tan(a) "
            f"(L = {self.length_mm} mm, W/tan(a) = {self.width_mm / math.tan(math.radians(a)):.1f} mm)",
        )

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


@dataclass(frozen=True, kw_only=True)
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
        nonnegative("material", self, "K_el", "K_sh", "alpha1", "alpha2", "K_sh4", "K_sh6", "K_lock")
        g = self.gamma_lock_deg
        check(
            isinstance(g, (int, float)) and not isinstance(g, bool) and 0 < g < 90,
            "material.gamma_lock_deg",
            g,
            "must lie strictly between 0 and 90 degrees",
        )
        j = self.jamming_angle_deg
        check(
            isinstance(j, (int, float)) and not isinstance(j, bool) and 0 < j < 90,
            "material.jamming_angle_deg",
            j,
            "must lie strictly between 0 and 90 degrees",
        )
        steps = self.shear_stress_steps_Pa
        check(isinstance(steps, (list, tuple)), "material.shear_stress_steps_Pa", steps, "must be a list of numbers")
        object.__setattr__(self, "shear_stress_steps_Pa", tuple(steps))
        for v in self.shear_stress_steps_Pa:
            check(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
                "material.shear_stress_steps_Pa",
                v,
                "each rise must be a finite number >= 0 (a monotone table)",
            )
        check(
            len(self.shear_stress_steps_Pa) <= 40,
            "material.shear_stress_steps_Pa",
            len(steps),
            "at most 40 control points",
        )
        positive("material", self, "shear_table_i8_max")

    def internal_lengths_mm(self) -> tuple[float, float]:
        """l_i = sqrt(alpha_i / K_sh) [mm]: 309 mm and 31 mm for Table 1."""
        if self.K_sh == 0:
            return (math.inf, math.inf)
        return tuple(1e3 * math.sqrt(a / self.K_sh) for a in (self.alpha1, self.alpha2))  # type: ignore[return-value]


CONSTRAINTS = ("lagrange", "penalty")
PENALTY_FORMS = ("mixed", "full")
#: the shear laws a scene can name (``effects.shear_law``) and the material keys each one reads
SHEAR_LAW_KEYS: dict[str, tuple[str, ...]] = {
    "quadratic": ("K_sh",),
    "polynomial": ("K_sh", "K_sh4", "K_sh6"),
    "locking": ("K_sh", "K_lock", "gamma_lock_deg"),
    "table": ("shear_stress_steps_Pa", "shear_table_i8_max"),
}
SHEAR_LAWS = tuple(SHEAR_LAW_KEYS)


def law_leaves_unread(effects: Effects, name: str) -> str | None:
    """Why the continuum's shear energy under ``effects`` does not read the material key ``name``; None if it does.

    A coefficient of one shear law (:data:`SHEAR_LAW_KEYS`) is read only under that law with shear
    on. ``K_sh`` is always read: besides its laws it scales the multiplier and the jamming barrier.
    Keys of no law (the elongation, the bending stiffnesses) are not this rule's: None.
    """
    laws = [law for law, keys in SHEAR_LAW_KEYS.items() if name in keys]
    if not laws or name == "K_sh" or (effects.shear and effects.shear_law in laws):
        return None
    reader = "effects.shear = false" if not effects.shear else f"effects.shear_law = {effects.shear_law!r}"
    return f"{reader} does not read material.{name} (shear_law = {' or '.join(map(repr, laws))} does)"


@dataclass(frozen=True, kw_only=True)
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
        boolean("effects", self, "shear", "elongation", "bending", "jamming")
        choice("effects", self, "constraint", CONSTRAINTS)
        choice("effects", self, "penalty_form", PENALTY_FORMS)
        choice("effects", self, "shear_law", SHEAR_LAWS)
        check(
            self.shear or self.shear_law == "quadratic",
            "effects.shear_law",
            self.shear_law,
            "a shear law needs effects.shear = true",
        )
        auto_or(
            "effects",
            self,
            "stabilization_K",
            lambda v: isinstance(v, (int, float)) and math.isfinite(v) and v >= 0,
            'a number >= 0 [Pa] (0: off); "auto" is K_s = 0.1 min(alpha1, alpha2) / h_T^2',
        )
        positive("effects", self, "penalty_K")
        check(
            self.elongation,
            "effects.elongation",
            self.elongation,
            "the yarn elongation term is what makes the yarns resist stretching; without it the "
            "tangent is singular (inextensible yarns would need a constraint ngbet does not model)",
        )
        check(
            self.shear or self.bending,
            "effects.shear",
            self.shear,
            "with neither shear nor bending nothing resists the shear of the yarn network",
        )

    @property
    def fields(self) -> tuple[str, ...]:
        """Names of the unknown fields this scene needs, in the order of the compound space."""
        if not self.bending:
            return ("u",)
        if self.constraint == "lagrange" or self.penalty_form == "mixed":
            return ("u", "phi", "lam")
        return ("u", "phi")


#: the tests a scene describes (top-level ``test``)
TESTS = ("bias_extension", "picture_frame")


def load_symbol(test: str) -> str:
    """The name of a test's load in messages: ``u0`` (the clamp displacement), ``d`` (a frame's crosshead travel)."""
    return "d" if test == "picture_frame" else "u0"


#: how the picture frame's clamps hold the arms of the cross (PictureFrame.arms)
ARMS = ("held", "sheared")


@dataclass(frozen=True, kw_only=True)
class PictureFrame:
    """The picture-frame test (test = "picture_frame"): a rigid frame of four bars hinged at its corners.

    The crosshead pulls one pin away from the opposite one along e1 (``loading.u0_mm`` is its travel d);
    the bars rotate about the pins and the frame turns from a square into a rhombus of frame angle θ,
    cos θ = (√2 L + d) / (2 L), shear angle γ = 90° − 2θ (L = ``frame_mm``). The specimen is a cross:
    a square of side ``frame_mm`` (pin to pin) whose four corner squares of side
    (``frame_mm`` − ``fabric_mm``)/2 are cut away, its four arms clamped to the bars. ``arms`` says
    how: ``"held"`` (the default), clamped over their length, they move with the frame and only the
    inner square of side ``fabric_mm`` shears (the benchmark's specimen, and the assumption of the
    normalisation Eq. 10); ``"sheared"``, held at their ends on the bars only, the arms shear with
    the inner square. The yarns run along the bars
    (at ±``specimen.yarn_angle_deg`` to e1, 45° for a fabric aligned with the frame), turned by
    ``misalignment_deg`` in the plane.
    """

    frame_mm: float = 145.0  # L_frame: side of the frame, pin to pin [mm]
    fabric_mm: float = 120.0  # L_fabric: side of the inner fabric square, between the arms [mm]
    # deg: both yarn families turned by this angle (counter-clockwise) from the bars: the fabric laid
    # in the frame out of line, the test's known sensitivity (the yarns are then stretched as the frame shears)
    misalignment_deg: float = 0.0
    # how the clamps hold the arms of the cross: "held" (over their length: only the inner square
    # shears, as Eq. 10 assumes) or "sheared" (at their ends on the bars: the arms shear with it)
    arms: str = "held"

    def __post_init__(self) -> None:
        positive("picture_frame", self, "frame_mm", "fabric_mm")
        choice("picture_frame", self, "arms", ARMS)
        check(
            self.frame_mm <= MAX_SPECIMEN_MM,
            "picture_frame.frame_mm",
            self.frame_mm,
            f"must be at most {MAX_SPECIMEN_MM:g} mm (1 km): larger values overflow the computation",
        )
        check(
            self.fabric_mm <= self.frame_mm,
            "picture_frame.fabric_mm",
            self.fabric_mm,
            f"the fabric square must fit in the frame: fabric_mm <= frame_mm = {self.frame_mm:g} mm",
        )
        m = self.misalignment_deg
        check(
            isinstance(m, (int, float)) and not isinstance(m, bool) and math.isfinite(m) and abs(m) <= 45.0,
            "picture_frame.misalignment_deg",
            m,
            "must lie between -45 and 45 degrees: beyond, the yarns lie nearer the other bars, which is "
            "the misalignment 90 degrees less with the families swapped (at 45 the yarns run along the diagonals)",
        )

    @property
    def arm_mm(self) -> float:
        """The side c = (L_frame − L_fabric)/2 of the cut-away corner squares [mm]."""
        return 0.5 * (self.frame_mm - self.fabric_mm)

    @property
    def fabric_area_mm2(self) -> float:
        """The area of the fabric that the model shears [mm²]: the cross, or the inner square when the arms are held."""
        if self.arms == "held":
            return self.fabric_mm**2
        return self.frame_mm**2 - 4 * self.arm_mm**2

    @property
    def locking_mm(self) -> float:
        """The crosshead travel (2 − √2) L_frame at which the frame closes flat (θ = 0, γ = 90°) [mm]."""
        return (2.0 - math.sqrt(2.0)) * self.frame_mm
