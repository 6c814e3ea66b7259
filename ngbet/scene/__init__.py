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
in :mod:`ngbet.scene.document`. Each name is imported from the module that defines it.
"""

__all__: list[str] = []
