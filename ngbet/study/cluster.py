"""Cases on a dask.distributed cluster, never waiting forever.

The client submits :func:`~ngbet.study.executors.execute_case` for each case (``distributed.Client.submit``);
the workers need ngbet installed and return the run folder's files, which the client stores into
its cache (no shared file system needed). Bounded waits: an unreachable scheduler is a
:class:`SchedulerError` after :data:`SCHEDULER_TIMEOUT_S`; a scheduler without workers, at the start
or after losing all of them (killed, or their machine gone), after :data:`WORKER_TIMEOUT_S`. The
cases finished by then are stored, the others cancelled, and the message says how many of each.
A case whose worker died is resubmitted by dask to another worker (at most three times, then it
is an error of that case).
"""

from __future__ import annotations

import math
import os
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

from ..errors import NgbetError
from .executors import execute_case
from .model import Case

__all__ = ["POLL_S", "SCHEDULER_TIMEOUT_S", "WORKER_TIMEOUT_S", "SchedulerError", "run_dask", "worker_timeout_s"]

#: seconds to reach the scheduler
SCHEDULER_TIMEOUT_S = 5.0
#: seconds a study waits while the scheduler has no worker (NGBET_DASK_WORKER_TIMEOUT_S overrides)
WORKER_TIMEOUT_S = 60.0
POLL_S = 0.5


class SchedulerError(NgbetError):
    """The dask scheduler could not be reached, or has had no worker for too long; ``address`` names it."""

    def __init__(self, address: str, why: str, what: str = "cannot reach the dask scheduler at") -> None:
        super().__init__(f"{what} {address}: {why}")
        self.address = address


def worker_timeout_s() -> float:
    """:data:`WORKER_TIMEOUT_S`, or the environment's NGBET_DASK_WORKER_TIMEOUT_S."""
    try:
        return float(os.environ.get("NGBET_DASK_WORKER_TIMEOUT_S", WORKER_TIMEOUT_S))
    except ValueError:
        return WORKER_TIMEOUT_S


def run_dask(
    todo: list[Case], scheduler: str, threads: int, finished: Callable[[Case, dict[str, Any], Path | None], None]
) -> None:
    """Run the cases ``todo`` on the cluster at ``scheduler``, each handed to ``finished`` as it completes.

    ``finished(case, record, None)`` gets the case's record, which carries the run folder's files
    (no folder on this machine); a case whose task failed gets a record of status ``"error"``.
    Raises :class:`SchedulerError` when the scheduler cannot be reached within
    :data:`SCHEDULER_TIMEOUT_S` or has no worker for :func:`worker_timeout_s`; the cases finished
    by then have been handed on, the others are cancelled.
    """
    from distributed import Client

    try:
        client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S:g}s")  # type: ignore[no-untyped-call, unused-ignore]
    except Exception as exc:  # refused, timed out, or something that does not speak dask answered
        raise SchedulerError(scheduler, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}") from None
    with client:
        wait_s = worker_timeout_s()
        try:
            client.wait_for_workers(1, timeout=wait_s)
        except Exception:  # dask's TimeoutError (an OSError or asyncio's, by version)
            raise SchedulerError(
                scheduler, f"no worker joined within {wait_s:g} s; nothing was run", "no dask worker at the scheduler"
            ) from None
        futs = {
            client.submit(
                execute_case,
                c.scene.to_dict(),  # type: ignore[union-attr]
                threads,
                None,
                key=f"ngbet-case-{c.key}-{uuid.uuid4().hex[:6]}",
                pure=False,
            ): c
            for c in todo
        }
        _collect(client, futs, scheduler, wait_s, finished)


def _collect(
    client: Any,
    futs: dict[Any, Case],
    scheduler: str,
    wait_s: float,
    finished: Callable[[Case, dict[str, Any], Path | None], None],
) -> None:
    """Hand each future to ``finished`` as it completes; give up when the cluster stays without workers."""
    from distributed import wait

    pending = set(futs)
    alone_since: float | None = None
    try:
        while pending:
            try:
                done, pending = wait(list(pending), timeout=POLL_S, return_when="FIRST_COMPLETED")  # type: ignore[no-untyped-call, unused-ignore]
            except Exception:  # nothing finished within the poll (dask's TimeoutError)
                done, pending = set(), set(pending)
            pending = set(pending)
            for fut in done:
                finished(futs[fut], _result(fut), None)
            if not pending:
                break
            if _workers(client) > 0:
                alone_since = None
            elif alone_since is None:
                alone_since = time.monotonic()
            elif time.monotonic() - alone_since > wait_s:
                client.cancel(list(pending))
                raise SchedulerError(
                    scheduler,
                    f"no worker for {wait_s:g} s (killed or gone); "
                    f"{len(futs) - len(pending)} finished cases are kept in the cache, "
                    f"{len(pending)} not run",
                    "lost every dask worker of the scheduler at",
                )
    except KeyboardInterrupt:
        client.cancel([f for f in pending if not f.done()])
        for f in pending:
            if f.status == "finished":
                finished(futs[f], f.result(), None)
        raise


def _result(fut: Any) -> dict[str, Any]:
    try:
        return cast("dict[str, Any]", fut.result())
    except Exception as exc:  # the case's worker died (KilledWorker) or the task failed
        return {
            "status": "error",
            "error": f"{type(exc).__name__}: {exc}",
            "error_type": type(exc).__name__,
            "wall_s": math.nan,
        }


def _workers(client: Any) -> int:
    """The scheduler's workers now (0 when it does not answer)."""
    try:
        return len(client.scheduler_info(n_workers=-1).get("workers", {}))
    except TypeError:  # older distributed: no n_workers
        return len(client.scheduler_info().get("workers", {}))
    except Exception:
        return 0
