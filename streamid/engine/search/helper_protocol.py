"""The shared-memory protocol between :class:`~streamid.engine.search.parallel.EvalHelper` and its helper process.

Both sides of :mod:`streamid.engine.search.parallel` (the caller) and :mod:`streamid.engine.search._evalhelper` (the helper)
read and write the same two files of a private folder on ``/dev/shm``: a control file of int64 words (the
slots below: sequence numbers, the binding's sizes, the pre-drawn uniforms' PCG64 state, the data file's path)
and one data file per binding (:func:`_layout`: the uniforms, the regressors, the target and one batch's
members and results, each aligned to 64 bytes).  This module is that contract, so that the two sides cannot
disagree about it; the handshake's rules are in :mod:`streamid.engine.search.parallel`'s notes.
"""

from __future__ import annotations

import mmap
import os
import tempfile
from typing import Any

import numpy as np
from numpy.typing import NDArray

# Control words (int64 slots of the control file).
_QUIT, _PID, _BIND_SEQ, _BIND_ACK, _JOB_SEQ, _JOB_BIND, _JOB_N, _JOB_SHARED = range(8)
_STARTED, _DONE, _SLEEPING, _N, _D, _M, _CAP, _ERRORS = range(8, 16)
_UNIFORMS, _DRAW_SEQ, _DRAW_N, _DRAW_READY = range(16, 20)
_DRAW_STATE = 20  # 4 words: PCG64 state (low, high), increment (low, high)
_CONTROL_BYTES = 4096
_FLOATS_AT = 512  # float64 slots: ridge
_PATH_AT, _PATH_MAX = 1024, 2048
_ALIGN = 64
_DRAW_CHUNK = 8192  # uniforms the helper draws between two looks for a batch (~18 us)


def _layout(n: int, d: int, m: int, cap: int, uniforms: int) -> dict[str, tuple[int, tuple[int, ...], Any]]:
    """Offsets, shapes and dtypes of one binding's data file (the same on both sides)."""
    parts = [
        ("uniforms", (uniforms,), np.float64),
        ("R", (n, d), np.float64),
        ("target", (n,), np.float64),
        ("masks", (cap, d), np.bool_),
        ("centres", (cap, m, d), np.float64),
        ("widths", (cap, m), np.float64),
        ("out", (cap,), np.float64),
    ]
    out, off = {}, 0
    for name, shape, dt in parts:
        out[name] = (off, shape, dt)
        size = int(np.prod(shape)) * np.dtype(dt).itemsize
        off += -(-size // _ALIGN) * _ALIGN
    out["_size"] = (off, (), np.uint8)
    return out


def _views(mm: mmap.mmap, layout: dict[str, tuple[int, tuple[int, ...], Any]]) -> dict[str, NDArray[Any]]:
    return {
        k: np.frombuffer(mm, dtype=dt, count=int(np.prod(shape)), offset=off).reshape(shape)
        for k, (off, shape, dt) in layout.items()
        if k != "_size"
    }


def _shm_dir() -> str:
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else tempfile.gettempdir()


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _remove_folder(folder: str) -> None:
    """Remove the helper's private folder and every file in it (only ever files of ours: mkdtemp)."""
    try:
        names = os.listdir(folder)
    except FileNotFoundError:
        return
    for name in names:
        _unlink(os.path.join(folder, name))
    try:
        os.rmdir(folder)
    except OSError:
        pass
