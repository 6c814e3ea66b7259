"""Parameter studies: a list (or grid) of scene variants, each run once into a cache.

The modules, by job:

- :mod:`~ngbet.study.model`: :class:`Study` (base scene, cases, figures, report) and
  :class:`StudyData` (what a study wrote, read back);
- :mod:`~ngbet.study.reads`: which keys the cases read (a varied key none reads is refused);
- :mod:`~ngbet.study.keys`: the cache key of a case (its scene and the code it runs);
- :mod:`~ngbet.study.cache`: storing, verifying and cleaning the case cache; the locks of live studies;
- :mod:`~ngbet.study.executors`: running a case, local worker processes;
- :mod:`~ngbet.study.cluster`: dask.distributed, with bounded waits;
- :mod:`~ngbet.study.collect`: the study folder (tables, meta.json) and reading it back;
- :mod:`~ngbet.study.figures`: figures and report;
- :mod:`~ngbet.study.runner`: :func:`run_study`, which ties them together;
- :mod:`~ngbet.study.command`: the command line of a study.

Each name is imported from the module that defines it. The studies themselves are in
:mod:`ngbet.studies` (their list: ``ngbet.studies.STUDIES``).
"""

__all__: list[str] = []
