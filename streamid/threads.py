"""``thread_map``: a function over items in a few threads, for numerics that release the GIL."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

__all__ = ["cores", "thread_map"]

J = TypeVar("J")
R = TypeVar("R")


def thread_map(fn: Callable[[J], R], items: Sequence[J], threads: int) -> list[R]:
    """``fn`` applied to every item, in order: in this thread when ``threads <= 1`` or there is one item,
    else in a pool of ``min(threads, len(items))`` threads made for the call. For numerics that release
    the GIL (LAPACK, the compiled free runs) on a core the caller knows to be free (an
    :class:`~streamid.engine.search.parallel.EvalHelper`'s, idle between search batches)."""
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(threads, len(items))) as ex:
        return list(ex.map(fn, items))


def cores() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count()`` where the platform has none):
    what a command a user runs (``streamid validate``, one ``identify``) may spend on its own numerics."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)
