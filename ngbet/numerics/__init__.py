"""Model-free numerics: load stepping, Newton, chord rows, relaxation, arc length, linear algebra.

Nothing here knows fabrics, scenes, run folders or figures: a model hands a problem that
satisfies the protocols of :mod:`.newton` (the state, its residual, energy, factorizations and
solves; the capabilities :class:`~ngbet.numerics.newton.Relaxable`,
:class:`~ngbet.numerics.newton.Locating` and :class:`~ngbet.numerics.newton.JammingWatch` where it has
them) and settings (:mod:`.settings`), and iterates the generator of step records it gets back.

engine       the load stepping of both models: step control, stops, growth and cut; a generator
newton       the problem protocols; damped Newton at a fixed load and what its failures say
path         the saddle-point corrector on the engine; displacement control, arc length or both
chord        rows of an output grid corrected with the factorization at hand
relax        a stable equilibrium at a fixed load where Newton failed on a short increment
arclength    pseudo-arclength continuation through turning points and bifurcations
linear       the Newton matrix of an NGSolve energy form: condensation, inverse, factorization
compiled     the energy integrand interpreted or as native code, cached across processes
settings     the numerics' settings (the runner translates a scene into them)
"""

__all__: list[str] = []
