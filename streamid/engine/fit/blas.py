"""One BLAS thread around the engine's numerics (set at run time, never at import).

OpenBLAS's default two threads make the many small matrix products of a
population evaluation slow and erratic on this project's 2-core machines
(STACK.md); one thread is steady. ``threadpoolctl.threadpool_limits`` scans the
loaded libraries on every call (~0.2 ms), so one :class:`ThreadpoolController`
is made on first use and reused (a cache, not configuration: the limit is
applied only inside the ``with`` blocks and restored on exit).
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from functools import lru_cache
from typing import Any

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread"]


@lru_cache(maxsize=1)
def _controller() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager[Any]:
    """Context manager limiting BLAS to one thread (restores the previous limits on exit)."""
    return _controller().limit(limits=1, user_api="blas")  # type: ignore[no-any-return]
