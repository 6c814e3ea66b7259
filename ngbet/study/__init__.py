"""Parameter studies: a list (or grid) of scene variants, each run once into a cache.

The modules, by job:

- :mod:`~ngbet.study.model`: :class:`Study` (base scene, cases, figures, report) and
  :class:`StudyData` (what a study wrote, read back);
- :mod:`~ngbet.study.keys`: the cache key of a case (its scene and the code it runs);
- :mod:`~ngbet.study.cache`: storing, verifying and cleaning the case cache; the locks of live studies;
- :mod:`~ngbet.study.executors`: running a case, local worker processes;
- :mod:`~ngbet.study.cluster`: dask.distributed, with bounded waits;
- :mod:`~ngbet.study.collect`: the study folder (tables, meta.json) and reading it back;
- :mod:`~ngbet.study.figures`: figures and report;
- :mod:`~ngbet.study.runner`: :func:`run_study`, which ties them together;
- :mod:`~ngbet.study.command`: the command line of a study.

The studies themselves are in :mod:`ngbet.studies` (their list: ``ngbet.studies.STUDIES``).
"""

from .cache import CacheError, clean_debris, verify_case
from .cluster import SchedulerError
from .collect import StudyFolderError, load
from .command import add_arguments, build_study, left_out, main_for, run_from_args
from .executors import StudyInterrupted, execute_case
from .figures import finish, plot_only, savefig
from .keys import case_key, code_version, grid
from .model import MissingValueError, Study, StudyData
from .runner import DEFAULT_ROOT, default_out, run_study

__all__ = ["DEFAULT_ROOT", "CacheError", "MissingValueError", "SchedulerError", "Study", "StudyData",
           "StudyFolderError", "StudyInterrupted", "add_arguments", "build_study", "case_key", "clean_debris",
           "code_version", "default_out", "execute_case", "finish", "grid", "left_out", "load", "main_for",
           "plot_only", "run_from_args", "run_study", "savefig", "verify_case"]
