"""Parameter studies of ngbet: one module per study, each runnable as ``python -m ngbet.studies.NAME``.

This folder is the package ``ngbet.studies`` (installed from the top-level ``studies/`` of the
repository). Each module defines ``build(quick: bool = False, scene: Scene | None = None) ->
ngbet.study.model.Study`` (``scene``: the base scene, default ``ngbet.default_scene()``) and ``main``.
``ngbet study NAME [scene.toml] [--set ...]`` runs the same thing. A new study is a module here
and one line in :data:`STUDIES`, the one list of the studies (and its name in
:data:`PICTURE_FRAME` when it serves that test). See docs/studies.md.
"""

__all__ = ["PICTURE_FRAME", "STUDIES"]

STUDIES = {
    "penalty_p": "penalty K x p (and h) convergence against the Lagrange solution and the scene's reference "
    "(bias extension)",
    "work_precision": "error of the force and of the mid-axis profile at 56 mm versus wall time (bias extension)",
    "alpha1": "alpha1 sweep at 56 mm, including the balanced fabric alpha1 = alpha2 (bias extension)",
    "kel": "K_el sweep at 37 mm: deformed outlines (bias extension)",
    "curves": "load-displacement and double-force-displacement curves with the ideal-kinematics estimate "
    "(bias extension)",
    "maps": "deformed specimen coloured by the shear angle, yarns drawn on it (37 and 56 mm; "
    "bias extension and picture frame)",
    "compare": "continuum and discrete model side by side (bias extension)",
    "validation": "Twintex fabrics of Cao et al. 2008: every measured curve a fit did not use, predicted "
    "(from a fabric's bias-extension scene; its picture-frame curves included)",
    "reference": (
        "reference-grade force (37, 56 mm) and profile by hp extrapolation, with its bound; hp vs uniform "
        "convergence (bias extension)"
    ),
}
#: the studies made for the picture-frame test as well (``ngbet sweep`` serves both tests too); the
#: others are made for the bias extension test only: their figures and reports read its specimen,
#: and they refuse a picture-frame scene before anything runs
PICTURE_FRAME = ("maps",)
