"""Samples of a log as arrays, and arrays as a log (the file access is :mod:`streamid.logs.mcap_files`'s).

:func:`read_log_arrays` concatenates a stream's sample batches (aligning
``.../u`` and ``.../y`` batches on their common sample times) for
identification; :func:`write_arrays_log` writes uniformly sampled arrays as
batches, as a device would publish them.  Both are re-exported by
:mod:`streamid.logs.mcap_files`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from streamid.wire import codec
from streamid.errors import CodecError, ConfigError, LogError
from streamid.wire.keys import SAMPLE_KINDS, parse_key
from streamid.logs.mcap_files import LogReader, LogWriter

__all__ = ["LogArrays", "read_log_arrays", "write_arrays_log"]


@dataclass(frozen=True)
class LogArrays:
    """The samples of one stream of a log, concatenated and aligned.

    ``t_ns`` (int64, strictly increasing), ``inputs``/``outputs`` (name ->
    float64 array of the same length), ``period_ns`` (the batches' period, or
    the median spacing when the batches carry per-sample times).
    """

    stream: str
    t_ns: NDArray[np.int64]
    inputs: dict[str, NDArray[np.float64]]
    outputs: dict[str, NDArray[np.float64]]
    period_ns: int
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def u(self) -> NDArray[np.float64]:
        """Inputs as an ``(N, n_inputs)`` array, columns in channel order."""
        return np.column_stack(list(self.inputs.values())) if self.inputs else np.empty((len(self), 0))

    def y(self) -> NDArray[np.float64]:
        """Outputs as an ``(N, n_outputs)`` array, columns in channel order."""
        return np.column_stack(list(self.outputs.values())) if self.outputs else np.empty((len(self), 0))


def _role_series(
    path: Path, batches: list[codec.SampleBatch], role: str
) -> tuple[NDArray[np.int64], dict[str, NDArray[np.float64]]]:
    parts = [b for b in batches if (b.inputs if role == "input" else b.outputs)]
    if not parts:
        return np.empty(0, np.int64), {}
    parts.sort(key=lambda b: (b.t0_ns, b.seq))
    names = list((parts[0].inputs if role == "input" else parts[0].outputs))
    kept: list[codec.SampleBatch] = []
    for b in parts:
        chans = b.inputs if role == "input" else b.outputs
        if list(chans) != names:
            raise LogError(
                f"{path}: every {role} batch of stream {b.stream!r} must carry the same channels; "
                f"batch seq {b.seq} has {list(chans)}, the first had {names}"
            )
        if kept and kept[-1].seq == b.seq and kept[-1].t0_ns == b.t0_ns:
            continue  # duplicate (e.g. a batch recorded twice)
        kept.append(b)
    t = np.concatenate([b.times_ns() for b in kept])
    if t.size > 1 and not bool(np.all(t[1:] > t[:-1])):
        i = int(np.argmin(t[1:] > t[:-1]))
        raise LogError(
            f"{path}: {role} sample times of stream {kept[0].stream!r} must be strictly "
            f"increasing across batches; t_ns[{i + 1}] = {int(t[i + 1])} after {int(t[i])} "
            f"(overlapping batches)"
        )
    chans = {n: np.concatenate([(b.inputs if role == "input" else b.outputs)[n] for b in kept])
             for n in names}
    return t, chans


def read_log_arrays(
    path: str | os.PathLike[str],
    stream: str | None = None,
    *,
    partial: bool = False,
) -> LogArrays:
    """Concatenate a stream's sample batches into arrays.

    Batches on ``streamid/<s>/samples`` give inputs and outputs together;
    batches on ``.../u`` and ``.../y`` are aligned on their common sample
    times (exact nanosecond match).

    Parameters
    ----------
    path : str or Path
        An MCAP log.
    stream : str, optional
        Which stream; may be omitted when the log holds exactly one.
    partial : bool
        Read every complete chunk of a damaged file instead of failing.

    Raises
    ------
    LogError
        Unreadable file, unknown/ambiguous stream, undecodable batch, or
        inconsistent batches.
    """
    path = Path(path)
    reader = LogReader(path, partial=partial)
    by_stream: dict[str, list[codec.SampleBatch]] = {}
    for key, t_log, data in reader:
        try:
            s, kind = parse_key(key)
        except ConfigError:
            continue
        if kind not in SAMPLE_KINDS or (stream is not None and s != stream):
            if kind in SAMPLE_KINDS:
                by_stream.setdefault(s, [])
            continue
        try:
            batch = codec.decode(data)
        except CodecError as exc:
            raise LogError(f"{path}: message on {key!r} logged at {t_log} ns is not a valid "
                           f"sample batch: {exc}") from exc
        # a batch on .../u carries inputs, on .../y outputs; keep only that role
        if kind == "u" and batch.outputs or kind == "y" and batch.inputs:
            raise LogError(f"{path}: batch on {key!r} (seq {batch.seq}) carries "
                           f"{'outputs' if kind == 'u' else 'inputs'}; .../u batches carry only "
                           f"inputs and .../y batches only outputs")
        by_stream.setdefault(s, []).append(batch)
    if stream is None:
        found = [s for s, b in by_stream.items()]
        if len(found) != 1:
            raise LogError(
                f"{path}: pass the stream name; the log must hold exactly one stream to omit it, "
                f"found {found or 'none'}"
            )
        stream = found[0]
    batches = by_stream.get(stream) or []
    if not batches:
        raise LogError(f"{path}: no sample batches of stream {stream!r}; streams in the log: "
                       f"{sorted(by_stream) or 'none'}")
    t_u, u = _role_series(path, batches, "input")
    t_y, y = _role_series(path, batches, "output")
    if not u or not y:
        t = t_u if u else t_y
    elif t_u.shape == t_y.shape and np.array_equal(t_u, t_y):
        t = t_u
    else:
        t, iu, iy = np.intersect1d(t_u, t_y, assume_unique=True, return_indices=True)
        if t.size == 0:
            raise LogError(f"{path}: the input and output batches of stream {stream!r} share no "
                           f"sample time; u and y must be sampled on a common clock")
        u = {k: v[iu] for k, v in u.items()}
        y = {k: v[iy] for k, v in y.items()}
    periods = {b.period_ns for b in batches if b.t_ns is None}
    if len(periods) == 1:
        period = periods.pop()
    elif t.size > 1:
        period = int(np.median(np.diff(t)))
    else:
        period = max([b.period_ns for b in batches] + [0])
    return LogArrays(stream, t.astype(np.int64, copy=False), u, y, int(period), reader.metadata)


def write_arrays_log(
    path: str | os.PathLike[str],
    stream: str,
    inputs: Mapping[str, NDArray[np.float64]],
    outputs: Mapping[str, NDArray[np.float64]],
    *,
    period_ns: int,
    t0_ns: int = 0,
    batch_size: int = 100,
    split: bool = False,
    metadata: Mapping[str, str] | None = None,
) -> int:
    """Write uniformly sampled arrays as a streamid log of sample batches.

    Each batch of ``batch_size`` samples is one message on
    ``streamid/<stream>/samples`` (or, with ``split=True``, one message on
    ``.../u`` with the inputs and one on ``.../y`` with the outputs, as from a
    DAC and a separate sensor).  ``log_time`` is the time of the batch's last
    sample (when a device would have sent it); ``seq`` counts batches from 0.

    Returns
    -------
    int
        Number of messages written.
    """
    if batch_size < 1:
        raise ConfigError(f"batch_size must be >= 1 sample; got {batch_size!r}")
    lengths = {len(v) for v in list(inputs.values()) + list(outputs.values())}
    if len(lengths) != 1:
        raise ConfigError(f"every channel must have the same length; got lengths {sorted(lengths)}")
    n = lengths.pop()
    count = 0
    with LogWriter(path, metadata=metadata) as w:
        for seq, start in enumerate(range(0, n, batch_size)):
            stop = min(start + batch_size, n)
            t0 = t0_ns + start * period_ns
            t_last = t0_ns + (stop - 1) * period_ns
            ins = {k: np.asarray(v[start:stop], dtype=np.float64) for k, v in inputs.items()}
            outs = {k: np.asarray(v[start:stop], dtype=np.float64) for k, v in outputs.items()}
            roles = [(ins, {}), ({}, outs)] if split else [(ins, outs)]
            roles = [(i, o) for i, o in roles if i or o]
            for i, o in roles:
                batch = codec.SampleBatch(stream, seq, t0, period_ns, None, i, o)
                w.write(batch.key(), codec.encode(batch), t_last, t0)
                count += 1
    return count
