"""Flat resident memory: let the C allocator keep and reuse the identifications' working memory.

Why.  Every identification builds its working buffers afresh and frees them at
its end: for a 0.5 s window of the 20 kHz piezo stream (7,000 estimation
samples) the engine's batched population evaluation alone takes ~40 MB (feature
table P x (D + 2) x n and activations P x (M + 1) x n, measured with
``tracemalloc``: Python-level memory is otherwise flat at ~12 MB, nothing
leaks).  With glibc's defaults each worker thread gets its own malloc arena and
the mmap/trim thresholds adapt to the allocation history, so after an update
those pages are sometimes returned to the kernel and sometimes kept -- in one or
two arenas, depending on which worker ran the big stream last.  The resident
set of the 8 x 2 kHz + 20 kHz load therefore jumped between ~90, ~135 and
~175 MB from one second to the next although nothing grew.

What.  :func:`retain_freed_memory` (glibc only; a no-op elsewhere) sets, with
``mallopt``:

* ``M_ARENA_MAX = 1``: every thread allocates from the main arena, so the
  working memory freed by one worker is what the next identification reuses,
  whichever worker runs it (Zenoh's and Python's small allocations go through
  glibc's per-thread caches first; ingestion speed was measured unchanged);
* ``M_MMAP_THRESHOLD = 64 MiB`` and ``M_TRIM_THRESHOLD = 1 GiB`` (which also
  turn the adaptive thresholds off): buffers below 64 MiB come from the heap
  and freed heap memory is kept for reuse instead of being unmapped and faulted
  in again at the next update.

The resident set then sits at the high-water mark of the working memory
(measured flat within 1 % over 2 minutes of that load, see
``docs/reliability.md``).  Buffers above 64 MiB (windows of ~100k samples)
are still mapped and unmapped per update.  The settings are process-wide:
:class:`~streamid.daemon.service.Daemon` applies them at start unless
``[daemon] retain_memory = false``.

Giving memory back.  Received payloads are the exception to "keep and reuse":
a large batch (up to ``[daemon] max_payload_bytes``, 16 MiB by default, and
whatever Zenoh received before the size was checked) is copied two or three
times on its way in, and those copies, below the 64 MiB threshold, stay in the
heap.  :func:`give_back_freed_memory` (``malloc_trim(0)``) returns every free
page of the heap to the kernel; the daemon calls it after a payload of at
least :data:`LARGE_PAYLOAD` bytes was received or refused (at most once a
second, from the housekeeping thread), so a burst of large payloads does not
leave the resident set at its peak.
"""

from __future__ import annotations

import ctypes
import logging
import platform

__all__ = ["retain_freed_memory", "give_back_freed_memory", "MMAP_THRESHOLD", "TRIM_THRESHOLD", "LARGE_PAYLOAD"]

_log = logging.getLogger(__name__)

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
#: allocations below this come from the heap (and are reused once freed)
MMAP_THRESHOLD = 64 << 20
#: free heap memory kept before any is returned to the kernel
TRIM_THRESHOLD = 1 << 30
#: A payload at least this large makes the daemon give free heap memory back afterwards.
LARGE_PAYLOAD = 1 << 20


def retain_freed_memory() -> bool:
    """Make glibc keep and reuse freed working memory (one arena, fixed thresholds).

    Returns
    -------
    bool
        Whether the settings were applied (False on other C libraries, or if
        ``mallopt`` refused one of them).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = all(
        mallopt(param, value) == 1
        for param, value in ((_M_ARENA_MAX, 1), (_M_MMAP_THRESHOLD, MMAP_THRESHOLD), (_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    )
    if not ok:
        _log.info("mallopt refused a setting: resident memory may swing with each identification")
    return ok


def give_back_freed_memory() -> bool:
    """Return the heap's free pages to the kernel (``malloc_trim(0)``; glibc only).

    Returns
    -------
    bool
        Whether glibc released any memory (False elsewhere).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return False
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return bool(trim(0))
