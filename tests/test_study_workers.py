"""The local worker processes of a study: forked by a fork server that has imported ngbet and NGSolve."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os

import pytest

from ngbet.scene.document import Scene
from ngbet.study import executors
from ngbet.study.model import Case

pytestmark = pytest.mark.skipif("forkserver" not in mp.get_all_start_methods(), reason="no fork server here")


def pool_getenv(name: str) -> str | None:
    """``os.getenv(name)`` in a worker of a fresh study pool (its fork server may be older)."""
    ctx = executors.worker_context([Case(0, {}, Scene(), "k")])
    alive_r, alive_w = ctx.Pipe(duplex=False)
    env = {k: v for k, v in os.environ.items() if k.startswith("NGBET_")}
    try:
        with cf.ProcessPoolExecutor(
            1, mp_context=ctx, initializer=executors.worker_init, initargs=(alive_r, env)
        ) as ex:
            return ex.submit(os.getenv, name).result(timeout=60)
    finally:
        alive_w.close()
        alive_r.close()


def test_workers_see_the_ngbet_variables_of_their_study_not_of_the_fork_server(monkeypatch):
    monkeypatch.setenv("NGBET_PROBE", "first")
    assert pool_getenv("NGBET_PROBE") == "first"  # the fork server runs from here on
    monkeypatch.setenv("NGBET_PROBE", "second")
    assert pool_getenv("NGBET_PROBE") == "second"
    monkeypatch.delenv("NGBET_PROBE")
    assert pool_getenv("NGBET_PROBE") is None
