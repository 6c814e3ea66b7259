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

The sections are defined in :mod:`ngbet.scene.physical` (specimen, material, effects) and
:mod:`ngbet.scene.numerical` (discretization, loading, solver, outputs, discrete, calibration), the
checks they run in :mod:`ngbet.scene.validate`, the whole scene with its TOML reading and writing
in :mod:`ngbet.scene.document`; every public name is importable from ``ngbet.scene``.
"""

from .document import _SECTIONS as _SECTIONS  # the section table, read by ngbet.scene_doc
from .document import (
    DEFAULT_DISCRETIZATION,
    MIN_YARNS_PER_FAMILY,
    MODELS,
    NOT_READ_BY,
    NOT_READ_BY_TEST,
    Scene,
    SceneNote,
    SceneWarning,
    apply_changes,
    default_scene,
    read_toml,
    yarns_per_family,
)
from .numerical import (
    FIELD_OUTPUTS,
    FIGURE_FORMATS,
    LINEAR_SOLVERS,
    MAX_ORDER,
    PAPER_STOPS_MM,
    Calibration,
    Discrete,
    Discretization,
    Loading,
    Outputs,
    Solver,
)
from .physical import (
    CONSTRAINTS,
    MAX_SPECIMEN_MM,
    PENALTY_FORMS,
    SHEAR_LAWS,
    TESTS,
    Effects,
    Material,
    PictureFrame,
    Specimen,
)
from .validate import AUTO, SceneError

__all__ = [
    "AUTO", "CONSTRAINTS", "DEFAULT_DISCRETIZATION", "FIELD_OUTPUTS", "FIGURE_FORMATS", "LINEAR_SOLVERS", "MAX_ORDER",
    "MAX_SPECIMEN_MM", "MIN_YARNS_PER_FAMILY", "MODELS", "NOT_READ_BY", "NOT_READ_BY_TEST", "PAPER_STOPS_MM",
    "PENALTY_FORMS", "SHEAR_LAWS", "TESTS", "Calibration", "Discrete", "Discretization", "Effects", "Loading",
    "Material", "Outputs", "PictureFrame", "Scene", "SceneError", "SceneNote", "SceneWarning", "Solver", "Specimen",
    "apply_changes", "default_scene", "read_toml", "yarns_per_family",
]
