"""Running a scene: the one translation of a scene into settings and threads, the load path consumed.

settings     the scene's numerics: Newton, linear algebra, load path, arc length, the network's steps
threads      NGSolve's and the BLAS pools' threads for a run (the one thread policy)
continuum    a continuum scene into a run folder (its load path iterated, each step written)
discrete     a network scene into a run folder (its load path iterated, each step written)
fields       the continuum's fields and an instability's mode as VTU files (mm)
arclength    arc length in a continuum run: its settings, diagnosis and record
sensitivity  the fits' force path and its derivatives (no run folder)
ladder       accuracy on demand: finer discretizations until the force error meets the target
"""

__all__: list[str] = []
