"""The whole scene: its sections together, TOML reading and writing, changes by dotted keys, the default.

A key the scene file leaves out takes the value of ``Scene()``, which is the default run's (:func:`default_scene`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import tomli_w

from .numerical import Calibration, Discrete, Discretization, Loading, Outputs, Solver
from .physical import TESTS, Effects, Material, PictureFrame, Specimen, law_leaves_unread
from .validate import AUTO, SceneError, check, choice

__all__ = [
    "DEFAULT_DISCRETIZATION",
    "MIN_YARNS_PER_FAMILY",
    "MODELS",
    "NOT_READ_BY",
    "NOT_READ_BY_TEST",
    "SECTIONS",
    "TOP_LEVEL",
    "Scene",
    "SceneNote",
    "SceneWarning",
    "apply_changes",
    "default_scene",
    "read_toml",
    "yarns_per_family",
]

MODELS = ("continuum", "discrete")
#: the scene's keys outside its sections: ``model`` (:data:`MODELS`) and ``test``
#: (:data:`ngbet.scene.physical.TESTS`)
TOP_LEVEL = ("model", "test")

#: what each model does not read: whole sections (None) or some of their keys. A non-default value
#: there is reported by name (:meth:`Scene.unused_keys`, a :class:`SceneWarning` on construction).
NOT_READ_BY: dict[str, dict[str, tuple[str, ...] | None]] = {
    "continuum": {"discrete": None},
    "discrete": {"material": None, "effects": None, "discretization": None, "solver": ("condense",)},
}

#: what each test does not read, as :data:`NOT_READ_BY` (the picture frame's specimen is the cross
#: that [picture_frame] describes)
NOT_READ_BY_TEST: dict[str, dict[str, tuple[str, ...] | None]] = {
    "bias_extension": {"picture_frame": None},
    "picture_frame": {"specimen": ("length_mm", "width_mm"), "discretization": ("structured",)},
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
            why = (
                f"discretization.mesh_size_mm = {h:g} is finer than the default corners"
                if finer
                else "a structured mesh cannot be graded"
            )
            d["corner_mesh_size_mm"] = 0.0
            warnings.warn(
                SceneNote(f"{key} = 0 (no corner grading) instead of the default {default:g}: {why}"), stacklevel=4
            )
    ld = data.get("loading")
    key = "loading.min_step_mm"
    default = Loading.min_step_mm
    if isinstance(ld, dict) and key not in explicit and ld.get("min_step_mm", default) == default:
        steps = [ld.get(k, getattr(Loading, k)) for k in ("first_step_mm", "max_step_mm")]
        smallest = min((v for v in steps if _number(v) and v > 0), default=default)
        if smallest < default:
            ld["min_step_mm"] = smallest
            warnings.warn(
                SceneNote(
                    f"{key} = {smallest:g} instead of the default {default:g}: the scene's load steps are smaller"
                ),
                stacklevel=4,
            )


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


SECTIONS: dict[str, type] = {
    "specimen": Specimen,
    "material": Material,
    "effects": Effects,
    "discretization": Discretization,
    "loading": Loading,
    "solver": Solver,
    "outputs": Outputs,
    "discrete": Discrete,
    "calibration": Calibration,
    "picture_frame": PictureFrame,
}


@dataclass(frozen=True, kw_only=True)
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
    test: str = "bias_extension"
    picture_frame: PictureFrame = field(default_factory=PictureFrame)

    def __post_init__(self) -> None:
        choice("", self, "model", MODELS)
        choice("", self, "test", TESTS)
        for name, cls in SECTIONS.items():
            check(isinstance(getattr(self, name), cls), name, getattr(self, name), f"must be a {cls.__name__}")
        # loads past ideal yarn locking are valid: the yarns are extensible (K_el), and the run
        # warns (locking_warning); ideal locking belongs to inextensible yarns
        check(
            self.discretization.target_error == 0 or self.outputs.reaction,
            "discretization.target_error",
            self.discretization.target_error,
            "is an accuracy of the clamp force: it needs outputs.reaction = true",
        )
        if self.model == "discrete":
            check(
                self.solver.branch == "stay",
                "solver.branch",
                self.solver.branch,
                "branch switching is for the continuum model (the discrete model follows the load)",
            )
            n = yarns_per_family(self.specimen, self.discrete.spacing_mm)
            check(
                n >= MIN_YARNS_PER_FAMILY,
                "discrete.spacing_mm",
                self.discrete.spacing_mm,
                f"leaves about {n} yarns per family across the {self.specimen.length_mm:g} x "
                f"{self.specimen.width_mm:g} mm specimen; a yarn network needs at least "
                f"{MIN_YARNS_PER_FAMILY} (spacing <= {_max_spacing(self.specimen):.3g} mm)",
            )
        if self.model == "continuum":
            check(
                self.solver.linear_solver != "cholmod" or self.solver.condense,
                "solver.linear_solver",
                self.solver.linear_solver,
                "needs solver.condense = true: the uncondensed Newton matrix holds "
                "the multiplier's block and is indefinite, which a Cholesky LL^T cannot factorize",
            )
            m, e = self.material, self.effects
            if e.shear and e.shear_law == "table":
                check(
                    len(m.shear_stress_steps_Pa) >= 2 and sum(m.shear_stress_steps_Pa) > 0,
                    "material.shear_stress_steps_Pa",
                    list(m.shear_stress_steps_Pa),
                    "effects.shear_law = 'table' needs at least 2 rises, not all 0",
                )
            elif e.shear:
                check(m.K_sh > 0, "material.K_sh", m.K_sh, "must be > 0 when effects.shear is on")
            check(m.K_el > 0, "material.K_el", m.K_el, "must be > 0 (effects.elongation is on)")
            rest = min(2 * self.specimen.yarn_angle_deg, 180 - 2 * self.specimen.yarn_angle_deg)
            check(
                not e.jamming or m.jamming_angle_deg < rest,
                "material.jamming_angle_deg",
                m.jamming_angle_deg,
                f"must be below the angle between the yarns at rest ({rest:g} degrees), else they jam at rest",
            )
            if e.bending:
                check(
                    m.alpha1 + m.alpha2 > 0,
                    "material.alpha1",
                    m.alpha1,
                    "alpha1 + alpha2 must be > 0 when effects.bending is on (else turn bending off)",
                )
                for fam, a in ((1, m.alpha1), (2, m.alpha2)):
                    check(
                        a > 0,
                        f"material.alpha{fam}",
                        a,
                        f"must be > 0 when effects.bending is on: without bending stiffness the yarns of family "
                        f"{fam} lose ellipticity where they are compressed, and the model has no mesh-independent "
                        "solution there (a small value, e.g. 1e-3 Pa m^2, keeps it well posed; or turn bending off)",
                    )
                d = self.discretization
                lam_set = d.order_lam != AUTO  # else the multiplier follows order_u: the order of phi is the key
                check(
                    d.p_lam < d.p_phi or e.fields == ("u", "phi"),
                    "discretization.order_lam" if lam_set else "discretization.order_phi",
                    d.order_lam if lam_set else d.order_phi,
                    f"the multiplier's order ({d.p_lam}{'' if lam_set else ', order_lam = auto: order_u - 2'}) "
                    f"must be below the order of phi ({d.p_phi}), else the constraint locks",
                )

        if self.test == "picture_frame":
            self._check_picture_frame()

        self._warn_unread()

    def _warn_unread(self) -> None:
        """A :class:`SceneWarning` for each set value that has no effect on the run the scene describes."""
        if self.model == "continuum":
            m, default = self.material, Material()
            for f in fields(m):
                why = law_leaves_unread(self.effects, f.name)
                if why and getattr(m, f.name) != getattr(default, f.name):
                    warnings.warn(SceneWarning(f"{why}: its value has no effect"), stacklevel=4)
        if self.unused_keys():
            warnings.warn(self.unused_warning(), stacklevel=4)
        replaced = self.discretization.chosen_by_target() if self.model == "continuum" else []
        if replaced:
            warnings.warn(
                SceneWarning(
                    f"discretization.target_error = {self.discretization.target_error:g} lets ngbet choose the mesh, "
                    f"its grading and the orders: the scene's {', '.join(replaced)} "
                    f"{'has' if len(replaced) == 1 else 'have'} no effect"
                ),
                stacklevel=4,
            )

    def _check_picture_frame(self) -> None:
        """What a picture-frame test needs of the rest of the scene."""
        check(
            self.model == "continuum",
            "model",
            self.model,
            "the picture-frame test is available for the continuum model only (test = 'picture_frame' "
            "needs model = 'continuum'): the yarn network has no frame",
        )
        pf, ld = self.picture_frame, self.loading
        lock = pf.locking_mm
        check(
            ld.u0_mm < lock,
            "loading.u0_mm",
            ld.u0_mm,
            f"the crosshead travel must stay below {lock:.4g} mm, where the frame of side "
            f"{pf.frame_mm:g} mm closes flat (shear angle 90 degrees)",
        )
        check(
            self.solver.path_following == "displacement",
            "solver.path_following",
            self.solver.path_following,
            "the picture frame follows the crosshead travel ('displacement'): arc length is available "
            "for the bias extension test only",
        )

    def unused_keys(self, tests: Sequence[str] = ()) -> list[str]:
        """The keys with a non-default value that the scene's model or test does not read ("section.key").

        ``tests``: the tests the scene runs, where it serves several (a fit of bias-extension and
        picture-frame curves); a key is then unused when none of them reads it. Default: its own test.
        """

        def holds(table: dict[str, tuple[str, ...] | None], name: str, key: str) -> bool:
            return name in table and (table[name] is None or key in (table[name] or ()))

        out = []
        for name in SECTIONS:
            section, default = getattr(self, name), SECTIONS[name]()
            for f in fields(section):
                if getattr(section, f.name) == getattr(default, f.name):
                    continue
                by_test = all(holds(NOT_READ_BY_TEST[t], name, f.name) for t in (tests or (self.test,)))
                if holds(NOT_READ_BY[self.model], name, f.name) or by_test:
                    out.append(f"{name}.{f.name}")
        return out

    def unused_warning(self, tests: Sequence[str] = ()) -> SceneWarning:
        """The warning that names :meth:`unused_keys` (``tests`` as there)."""
        unused = self.unused_keys(tests)
        every = tuple(dict.fromkeys(tests or (self.test,)))
        test = len(every) == 1 and (every[0] != "bias_extension" or any(k.startswith("picture_frame.") for k in unused))
        who = f"model = {self.model!r}" + (f" with test = {every[0]!r}" if test else "")
        return SceneWarning(f"{who} does not read {', '.join(unused)}: these values have no effect")

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
        known = {*TOP_LEVEL, *SECTIONS}
        for key in data:
            if key not in known:
                raise SceneError(f"unknown scene section '{key}'; known: {', '.join(sorted(known))}")
        kwargs: dict[str, Any] = {}
        for top in TOP_LEVEL:
            if top in data:
                kwargs[top] = data[top]
        for name, scls in SECTIONS.items():
            if name not in data:
                continue
            kwargs[name] = _section(name, scls, data[name])
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


def _section(name: str, scls: type, table: Any) -> Any:
    """The section ``name`` of class ``scls`` from its TOML table; unknown keys are refused by name."""
    if not isinstance(table, dict):
        raise SceneError(f"scene section '{name}' must be a table, got {table!r}")
    names = {f.name for f in fields(scls)}
    for key in table:
        if key not in names:
            raise SceneError(f"unknown scene key '{name}.{key}'; known in [{name}]: {', '.join(sorted(names))}")
    try:
        return scls(**table)
    except TypeError as exc:  # pragma: no cover - names are checked above
        raise SceneError(f"scene section '{name}': {exc}") from None


def read_toml(path: str | Path) -> dict[str, Any]:
    """The tables of a scene file; :class:`SceneError` naming the file when it cannot be read as TOML."""
    path = Path(path)
    raw = b""
    try:
        raw = path.read_bytes()
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
            raise SceneError(f'scene file {path} is UTF-16 text ("Unicode" in some editors); save it as UTF-8')
        # a byte-order mark (as some editors save UTF-8) is not TOML: read past it; CRLF lines are TOML
        return tomllib.loads(raw.decode("utf-8-sig"))
    except FileNotFoundError:
        raise SceneError(f"scene file not found: {path}") from None
    except IsADirectoryError:
        raise SceneError(f"scene file {path} is a directory, not a TOML file") from None
    except OSError as exc:
        raise SceneError(f"scene file {path} cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise SceneError(f"scene file {path} is not a text (UTF-8) file: is it a TOML scene?") from None
    except tomllib.TOMLDecodeError as exc:
        cr = b"\r" in raw and b"\n" not in raw  # a classic Mac file: TOML does not end a line in CR alone
        raise SceneError(
            f"scene file {path} is not valid TOML: {exc}"
            + ("; its lines end in CR alone, save it with LF (or CRLF) line ends" if cr else "")
        ) from None


def apply_changes(data: dict[str, Any], dotted: dict[str, Any]) -> dict[str, Any]:
    """The tables ``data`` with ``{"section.key": value}`` (or a :data:`TOP_LEVEL` key) set; a new dict."""
    d = {n: dict(t) if isinstance(t, dict) else t for n, t in data.items()}
    for key, value in dotted.items():
        value = _plain(value)
        section, _, name = key.partition(".")
        if not name:
            d[section] = value
            continue
        if section not in SECTIONS:
            raise SceneError(f"unknown scene section '{section}' in '{key}'")
        table = d.setdefault(section, {})
        if not isinstance(table, dict):
            raise SceneError(f"scene section '{section}' must be a table, got {table!r}")
        table[name] = value
    return d


def _plain(v: Any) -> Any:
    """A value with numpy scalars and arrays (``np.float32(2.0)``, ``np.int64(3)``) as Python's, in lists too."""
    if isinstance(v, (list, tuple)):
        return type(v)(_plain(x) for x in v)
    if type(v).__module__ == "numpy" and hasattr(v, "tolist"):  # a scalar's is the Python number, an array's a list
        return v.tolist()
    return v


MIN_YARNS_PER_FAMILY = 4


def yarns_per_family(specimen: Specimen, spacing_mm: float) -> int:
    """Yarns of one family across the specimen at a spacing [mm].

    The width of the rectangle across the yarns, L sin a + W cos a, over the spacing (the larger family count at
    a != 45 deg is not needed: both families use the smaller of the two widths).
    """
    a = math.radians(specimen.yarn_angle_deg)
    across = min(
        specimen.length_mm * math.sin(a) + specimen.width_mm * math.cos(a),
        specimen.length_mm * math.cos(a) + specimen.width_mm * math.sin(a),
    )
    return int(across // spacing_mm)


def _max_spacing(specimen: Specimen) -> float:
    return yarns_per_family(specimen, 1.0) / MIN_YARNS_PER_FAMILY


#: The default discretization (:class:`Discretization`'s defaults): the cheapest setting measured
#: within 0.3 % of the reference force at 56 mm (107.2365 N, ngbet.studies.reference) and within 1 % on the mid-axis
#: profile: 10 mm mesh graded to 0.25 mm at the four clamp corners, p = 3 (0.13 % and 0.39 %; its
#: solve takes 0.4–0.6 times that of the uniform 5 mm p = 2 mesh, which is 2.1 % and 7.8 % off,
#: measured interleaved on a loaded 2-core machine). p = 2 on the same mesh is 0.16 % on the force
#: but 4 % on the profile.
DEFAULT_DISCRETIZATION: dict[str, Any] = {
    k: getattr(Discretization, k) for k in ("mesh_size_mm", "corner_mesh_size_mm", "order_u")
}


def default_scene() -> Scene:
    """The paper's bias extension test: 70 x 220 mm, Table 1, Lagrange multiplier, u0 to 56 mm.

    On the accurate default discretization (:data:`DEFAULT_DISCRETIZATION`). The same scene as
    ``Scene()``: a scene file's missing keys take these values.
    """
    return Scene()
