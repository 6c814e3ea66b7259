"""Parameter studies of ngbet: one module per study, each runnable as ``python -m ngbet.studies.NAME``.

This folder is the package ``ngbet.studies`` (installed from the top-level ``studies/`` of the
repository). Each module defines ``build(quick: bool = False, scene: Scene | None = None) ->
ngbet.study.model.Study`` (``scene``: the base scene, default ``ngbet.default_scene()``) and ``main``.
``ngbet study NAME [scene.toml] [--set ...]`` runs the same thing. A new study is a module here
and one line in :data:`STUDIES`, the one list of the studies. See docs/studies.md.
"""

__all__ = ["STUDIES"]

STUDIES = {
    "penalty_p": "penalty K x p (and h) convergence against the Lagrange solution and the scene's reference",
    "work_precision": "error of the force and of the mid-axis profile at 56 mm versus wall time",
    "alpha1": "alpha1 sweep at 56 mm, including the balanced fabric alpha1 = alpha2",
    "kel": "K_el sweep at 37 mm: deformed outlines",
    "curves": "load-displacement and double-force-displacement curves with the ideal-kinematics estimate",
    "maps": "deformed specimen coloured by the shear angle, yarns drawn on it (37 and 56 mm)",
    "compare": "continuum and discrete model side by side",
    "validation": "Twintex fabrics of Cao et al. 2008: every measured curve a fit did not use, predicted",
    "reference": (
        "reference-grade force (37, 56 mm) and profile by hp extrapolation, with its bound; hp vs uniform convergence"
    ),
}
