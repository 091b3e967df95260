"""Samples given as numpy arrays, checked and made into :class:`~streamid.wire.codec.SampleBatch` es."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import DataError, StreamidError
from streamid.wire.codec import SampleBatch

__all__ = ["batch_of", "columns", "signal_names"]


def batch_of(
    stream: str, seq: int, t: NDArray[np.int64], u: NDArray[np.float64], y: NDArray[np.float64],
    in_names: tuple[str, ...], out_names: tuple[str, ...], period_ns: int,
) -> SampleBatch:
    """Arrays of consecutive samples as one batch (uniform times: ``period_ns`` from them; else explicit ``t_ns``)."""
    d = np.diff(t)
    uniform = t.size >= 2 and bool((d == d[0]).all()) and d[0] > 0
    try:
        batch = SampleBatch(
            stream, seq, int(t[0]),
            int(d[0]) if uniform else int(period_ns),
            None if uniform else t,
            {s: u[:, i] for i, s in enumerate(in_names)},
            {s: y[:, i] for i, s in enumerate(out_names)},
        )
    except StreamidError as exc:
        raise DataError(str(exc)) from exc
    return batch


def columns(a: ArrayLike, n: int, what: str) -> NDArray[np.float64]:
    """``a`` as float64 columns, one row per sample (a 1-D array is one column)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] != n:
        raise DataError(f"{what} must have shape ({n},) or ({n}, channels) to match t_ns; got {np.shape(a)}")
    return arr


def signal_names(names: Sequence[str] | None, k: int, base: str) -> tuple[str, ...]:
    """The names of ``k`` columns: as given, or ``base`` / ``base0, base1...``."""
    if names is None:
        return (base,) if k == 1 else tuple(f"{base}{i}" for i in range(k))
    out = (names,) if isinstance(names, str) else tuple(names)
    if len(out) != k:
        raise DataError(f"{len(out)} {base} name(s) {list(out)} given for {k} column(s)")
    return out
