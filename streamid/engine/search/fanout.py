"""``fan_out``: run independent jobs here or in spawned worker processes, results in job order (``thread_map``, in
threads: :mod:`streamid.threads`).

The one place the engine (``identify``'s restarts) and the ``streamid identify``
command (its ``--runs``) hand work to other processes. Workers are spawned,
never forked: the caller may hold a Zenoh session or threads. Results come
back in the order of the jobs whatever the number of workers, so a seeded
set of jobs gives the same results here or in a pool.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Any, TypeVar

from streamid.engine.search.parallel import EvalHelper

__all__ = ["fan_out"]

J = TypeVar("J")
R = TypeVar("R")


def fan_out(
    fn: Callable[..., R],
    jobs: Sequence[J],
    workers: int,
    *,
    executor: Executor | None = None,
    helper: EvalHelper | None = None,
    on_result: Callable[[list[R]], object] | None = None,
) -> list[R]:
    """``fn`` applied to every job, in the jobs' order.

    Parameters
    ----------
    fn : callable
        ``fn(job, helper=None) -> result``, a module-level function (a worker
        process imports it by name).
    jobs : sequence
        Picklable jobs when they go to worker processes.
    workers : int
        Worker processes; with no ``executor`` and ``min(workers, len(jobs)) <= 1``
        the jobs run in this process, one after the other, as ``fn(job, helper)``.
        Otherwise a pool of ``min(workers, len(jobs))`` spawned processes runs
        them as ``fn(job)`` and is shut down before returning.
    executor : concurrent.futures.Executor, optional
        Run the jobs on this executor (e.g. a long-lived pool, left running)
        instead of in this process or a pool of its own.
    helper : EvalHelper, optional
        Given to the jobs run in this process only (it cannot be sent to a worker).
    on_result : callable, optional
        ``on_result(results)`` after each result arrives (in order), with the
        results so far.

    Returns
    -------
    list
        One result per job, in the jobs' order.
    """
    results: list[R] = []
    n_workers = min(workers, len(jobs))
    if executor is None and n_workers <= 1:
        for job in jobs:
            results.append(fn(job, helper))
            if on_result is not None:
                on_result(results)
        return results
    own = executor is None
    ex: Executor = executor or ProcessPoolExecutor(
        max_workers=n_workers, mp_context=multiprocessing.get_context("spawn")
    )
    try:
        futures: list[Any] = [ex.submit(fn, job) for job in jobs]
        for fut in futures:
            results.append(fut.result())
            if on_result is not None:
                on_result(results)
    finally:
        if own:
            ex.shutdown(wait=True, cancel_futures=True)
    return results


