"""A data file's chosen signals as a streamid MCAP log: what ``streamid record convert`` writes and what
``streamid replay`` plays when given an MF4 file, a ROS 2 bag, a MATLAB or CSV file instead of a log.

The signals are read as ``streamid identify`` reads them (:func:`streamid.logs.datafile.load_record`: an MDF
file's or a bag's signals on the output's own timestamps, inputs zero-order held), and written as sample batches on
``streamid/<stream>/samples`` with each sample's own time (a bag's times are not exactly periodic; the batches say
so, ``t_ns`` per sample, the median step as their nominal period).  A file without a clock (a ``.mat``, a CSV
without a time column) needs the sample period.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from streamid.errors import ConfigError, DataError
from streamid.logs.datafile import Record, load_record
from streamid.logs.mcap_files import LogWriter
from streamid.wire import codec
from streamid.wire.keys import check_stream_name, is_valid_stream_name

__all__ = ["Converted", "convert_to_log", "is_streamid_log", "stream_name_for"]

#: Samples per batch written.
BATCH = 100


@dataclass(frozen=True)
class Converted:
    """What a conversion wrote."""

    path: Path
    stream: str
    samples: int
    messages: int
    period_ns: int
    record: Record


def stream_name_for(data: str | os.PathLike[str]) -> str:
    """A stream name from a file's name: its stem with every character a stream name refuses as ``_``."""
    stem = Path(data).name.split(".")[0] or "data"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem)[:128]
    return name if is_valid_stream_name(name) else "data"


def is_streamid_log(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is an MCAP file that is not a ROS 2 bag (so a streamid log, played as it is)."""
    from streamid.logs.ros2_bag import is_ros2_mcap

    p = Path(path)
    return p.is_file() and p.suffix.lower() == ".mcap" and not is_ros2_mcap(p)


def signals_wanted(path: str | os.PathLike[str], said: str) -> ConfigError | DataError:
    """The error for a data file given without ``--input``/``--output``: ``said`` (the accepted form) and what the
    file holds (an MDF file's channels, a bag's topics, a table's columns: the first 20), or why it cannot be read."""
    from streamid.logs.datafile import load_table
    from streamid.logs.timed import names_line

    try:
        table = load_table(path)
    except DataError as exc:  # an MDF file or a ROS 2 bag names its channels or topics (or says it is damaged)
        return DataError(f"{said}; {str(exc).split('; ', 1)[1]}" if "; it holds " in str(exc) else str(exc))
    return ConfigError(f"{said}; " + names_line(sorted(table.columns), "columns"))


def convert_to_log(
    data: str | os.PathLike[str],
    out: str | os.PathLike[str],
    inputs: Sequence[str],
    output: str,
    *,
    stream: str | None = None,
    period_ns: int | None = None,
    reading: Mapping[str, object] | None = None,
) -> Converted:
    """Write the signals ``inputs`` -> ``output`` of ``data`` as the streamid log ``out``.

    Raises
    ------
    DataError
        As :func:`load_record`; a file without a clock and no ``period_ns``.
    ConfigError
        A stream name out of its form, ``out`` the same file as ``data``.
    """
    name = check_stream_name(stream) if stream is not None else stream_name_for(data)
    if Path(out).exists() and Path(out).resolve() == Path(data).resolve():
        raise ConfigError(f"the log to write {str(out)!r} is the data file itself; give another file name")
    rec = load_record(data, list(inputs), output, **dict(reading or {}))  # type: ignore[arg-type]
    n = len(rec.y)
    if rec.t_ns is None:
        if not period_ns or period_ns <= 0:
            raise DataError(f"{rec.path} has no clock (no time column): give the sample period (--period-ms MS)")
        t = np.arange(n, dtype=np.int64) * int(period_ns)
        period = int(period_ns)
    else:
        t = np.asarray(rec.t_ns, dtype=np.int64)
        period = int(rec.period_ns or (int(np.median(np.diff(t))) if n > 1 else 0))
    uniform = n < 2 or bool(np.all(np.diff(t) == period))
    meta = {"converted_by": "streamid record convert", "source_file": Path(data).name,
            "inputs": ", ".join(inputs), "output": output, "resample": str(rec.info.get("clock", "the file's rows"))}
    messages = 0
    with LogWriter(out, metadata=meta) as w:
        for seq, start in enumerate(range(0, n, BATCH)):
            stop = min(start + BATCH, n)
            ins = {c: np.ascontiguousarray(rec.u[start:stop, j]) for j, c in enumerate(rec.input_names)}
            outs = {output: np.ascontiguousarray(rec.y[start:stop])}
            batch = codec.SampleBatch(name, seq, int(t[start]), period, None if uniform else t[start:stop], ins, outs)
            w.write(batch.key(), codec.encode(batch), int(t[stop - 1]), int(t[start]))
            messages += 1
    return Converted(Path(out), name, n, messages, period, rec)
