"""``python -m ngbet``: the command line.

``ngbet run`` runs in a forked child process that the command watches
(:mod:`ngbet.watch`). That process ends by :func:`ngbet.watch.end_run_process`.
"""

import os
import sys

from .cli import console
from .watch import SUPERVISED, end_run_process

__all__: list[str] = []


code = console()
if os.environ.get(SUPERVISED) and sys.argv[1:2] == ["run"]:
    end_run_process(code)
sys.exit(code)
