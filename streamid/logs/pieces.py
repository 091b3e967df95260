"""A CSV, Parquet or Arrow IPC (Feather) file's chosen columns read a piece at a time (a record of any length in
memory bounded by the piece: ``streamid validate`` on a long file, :mod:`streamid.engine.streamed`).

The same reading as :func:`streamid.logs.datafile.load_record` on a clean file, from the same code: the CSV's
layout (:func:`~streamid.logs.csv_table.csv_layout`: delimiter, decimal comma, header) and Arrow's readers
(:mod:`streamid.logs.arrow_tables`), the clock (the first time-like column, in the file's order, whose values all
increase strictly; for Parquet / Arrow then a timestamp or duration column) judged over the whole file as the
pieces pass, its period the median step (``int(np.median(np.diff(t_ns)))``'s value, exactly: each distinct step
counted as the pieces pass while there are at most :data:`MAX_STEPS`; a clock of more, jittered as real lab logs'
clocks are, has its two middle steps found by :func:`kth_steps` in passes over its column alone, 65,536 counts
each), the columns' checks (:class:`~streamid.logs.columns.ColumnStats`), the missing and infinite values
(:class:`~streamid.logs.gaps.GapStream`: ``--drop``, ``--fill`` or the error naming the rows, as
:func:`~streamid.logs.columns.handle_missing`). Whatever this reader does not do as ``load_record`` does raises
:class:`NotStreamable`, and the caller reads the file whole (which names the fault as today): a file that is not
plain text for Arrow, a column not in the file, a cell Arrow refuses, a run of
more than :data:`~streamid.logs.gaps.MAX_GAP_ROWS` rows with a missing value inside the record under ``--fill``
(:class:`LongRun`, which the caller names).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.logs.columns import ColumnStats
from streamid.logs.csv_table import DELIMITER_NAMES, CsvLayout, RowLines, csv_layout, time_unit_ns
from streamid.logs.gaps import GapStream, LongGap

__all__ = ["MAX_STEPS", "LongRun", "NotStreamable", "PieceReader", "kth_steps"]

#: A clock's distinct steps counted as they pass for its median period; a clock of more is read again
#: (its column only) for :func:`kth_steps`.
MAX_STEPS = 4096


class NotStreamable(Exception):
    """The file cannot be read a piece at a time as :func:`~streamid.logs.datafile.load_record` reads it whole."""


class LongRun(NotStreamable):
    """A run of rows with a missing value too long to hold under ``--fill`` (:class:`~streamid.logs.gaps.LongGap`):
    the message says so, for the caller to tell the user why the file is read whole."""


Steps = Callable[[], Iterator[NDArray[np.int64]]]


def kth_steps(steps: Steps, lo: int, hi: int, ks: Sequence[int], buckets: int = 1 << 16) -> list[int]:
    """The ``ks``-th smallest (0-based) of the integers ``steps()`` gives, all in ``lo..hi``, exactly: each pass over
    them (a call of ``steps``) counts them in ``buckets`` equal ranges of the one holding each wanted value, until
    the range is one value wide (at most 4 passes for any int64 range, one for a range of ``buckets`` values).
    Memory: the counts (``buckets`` a wanted value) and a piece."""
    span = {k: (lo, hi, k) for k in ks}  # the range holding the k-th value and its rank in that range
    found: dict[int, int] = {}
    while len(found) < len(span):
        open_ = {k: v for k, v in span.items() if k not in found}
        ranges = {(a, b) for a, b, _ in open_.values()}
        width = {r: -(-(r[1] - r[0] + 1) // buckets) for r in ranges}
        counts = {r: np.zeros(buckets, dtype=np.int64) for r in ranges}
        for d in steps():
            for (a, b), c in counts.items():
                inside = d[(d >= a) & (d <= b)]
                c += np.bincount((inside - a) // width[(a, b)], minlength=buckets)
        for k, (a, b, rank) in open_.items():
            w, cum = width[(a, b)], np.cumsum(counts[(a, b)])
            j = int(np.searchsorted(cum, rank, side="right"))
            rank -= int(cum[j - 1]) if j else 0
            a2 = a + j * w
            span[k] = (a2, min(b, a2 + w - 1), rank)
            if w == 1:
                found[k] = a2
    return [found[k] for k in ks]


class _Clock:
    """Whether a column is a clock (:func:`~streamid.logs.csv_table.clock_of`'s rules, or a timestamp column's),
    judged a piece at a time, and the count of each of its steps (ns) while they are at most :data:`MAX_STEPS`
    distinct (then their least and greatest: :meth:`period` counts them again in passes over the column)."""

    def __init__(self, unit: int | None) -> None:
        self.unit, self.ok, self.n = unit, True, 0
        self.first: float | None = None
        self.last_v, self.last_t = np.nan, 0
        self.steps: dict[int, int] | None = {}
        self.lo, self.hi = np.iinfo(np.int64).max, 0

    def times(self, v: NDArray[Any]) -> NDArray[np.int64]:
        if self.unit is None:
            return np.asarray(v, dtype=np.int64)
        with np.errstate(invalid="ignore", over="ignore"):
            return np.round(v * float(self.unit)).astype(np.int64)

    def add(self, v: NDArray[Any]) -> NDArray[np.int64]:
        t = self.times(v)
        if not v.size or not self.ok:
            return t
        if self.first is None:
            self.first = float(v[0])
            if self.unit is not None and not np.isfinite(v[0]):
                self.ok = False
        if self.n and not (v[0] > self.last_v and t[0] > self.last_t):
            self.ok = False
        if not (np.all(v[1:] > v[:-1]) and np.all(t[1:] > t[:-1])):
            self.ok = False
        if self.ok:
            d = np.diff(t) if not self.n else np.diff(np.concatenate([[self.last_t], t]))
            if d.size:
                self.lo, self.hi = min(self.lo, int(d.min())), max(self.hi, int(d.max()))
            if self.steps is not None:
                for k, c in zip(*np.unique(d, return_counts=True)):
                    self.steps[int(k)] = self.steps.get(int(k), 0) + int(c)
                if len(self.steps) > MAX_STEPS:
                    self.steps = None  # counted again by period()
        self.n += int(v.size)
        self.last_v, self.last_t = v[-1], int(t[-1])
        return t

    def period(self, column: Callable[[], Iterator[NDArray[Any]]]) -> int | None:
        """The median step (``int(np.median(np.diff(t_ns)))``'s value), None when the column is not a clock;
        ``column()`` gives the column's values again, a piece at a time (for a clock of more distinct steps)."""
        if not self.ok or self.n < 2 or self.first is None:
            return None
        if self.unit is not None and not (np.isfinite(self.last_v)
                                          and max(abs(self.first), abs(float(self.last_v))) * self.unit < 9e18):
            return None
        m = self.n - 1
        if self.steps is None:
            mid = np.array(kth_steps(lambda: self._steps(column), self.lo, self.hi, [(m - 1) // 2, m // 2]),
                           dtype=np.int64)
            return int(np.median(mid))
        keys = sorted(self.steps)
        counts = np.cumsum([self.steps[k] for k in keys])

        def kth(i: int) -> int:
            return keys[int(np.searchsorted(counts, i, side="right"))]

        mid = np.array([kth((m - 1) // 2), kth(m // 2)], dtype=np.int64)
        return int(np.median(mid))

    def _steps(self, column: Callable[[], Iterator[NDArray[Any]]]) -> Iterator[NDArray[np.int64]]:
        last: NDArray[np.int64] = np.empty(0, dtype=np.int64)
        for v in column():
            t = self.times(v)
            if t.size:
                yield np.diff(np.concatenate([last, t]))
                last = t[-1:]


class PieceReader:
    """The input and output columns of ``path`` a piece at a time (module docstring): :meth:`pieces`, then
    :meth:`finish` for how it was read. ``delimiter`` a CSV's (default detected).

    Raises
    ------
    NotStreamable
        Not a CSV, Parquet or Arrow file, or one this reader does not read as ``load_record`` does.
    """

    def __init__(self, path: str, inputs: Sequence[str], output: str, delimiter: str | None = None,
                 missing: str = "error") -> None:
        self.path, self.inputs, self.output = path, list(inputs), output
        from streamid.logs.datafile import COLUMNAR_KINDS

        kind = Path(path).suffix.lstrip(".").lower()
        self.used = list(dict.fromkeys([*inputs, output]))
        self.info: dict[str, Any] = {}
        self.stats = ColumnStats(inputs, output)
        self.gaps = GapStream(self.used, missing)
        self.rows = 0
        self.csv: CsvLayout | None = None
        if kind in ("csv", "tsv"):
            try:
                lay = csv_layout(Path(path), delimiter, self.used)
            except DataError as exc:
                raise NotStreamable(str(exc)) from None
            if not lay.plain or any(c not in lay.header for c in self.used):
                raise NotStreamable("not plain text for Arrow's reader, or a column not in the file")
            self.csv, self.names = lay, lay.wanted
            self.numeric_clocks = [c for c in lay.wanted if time_unit_ns(c) is not None]
            self.temporal: list[str] = []
            self.info = {"delimiter": DELIMITER_NAMES[lay.delimiter], "decimal": "," if lay.comma else "."}
        elif kind in COLUMNAR_KINDS:
            from streamid.logs.arrow_tables import open_columnar

            self.kind = COLUMNAR_KINDS[kind]
            try:
                names, temporal, unreadable, _, self.batches = open_columnar(path, self.kind)
            except Exception as exc:  # noqa: BLE001 - read whole, which names the fault
                raise NotStreamable(str(exc)) from None
            if any(c not in names or c in unreadable for c in self.used):
                raise NotStreamable("a column not in the file, or not numeric")
            self.names = [c for c in names if c not in unreadable and (c in self.used or time_unit_ns(c) is not None)]
            self.numeric_clocks = [c for c in self.names if time_unit_ns(c) is not None]
            self.temporal = [c for c in temporal if time_unit_ns(c) is not None]  # read_columnar's candidates
        else:
            raise NotStreamable(f"{kind!r} is not read a piece at a time")
        self.clocks = {c: _Clock(time_unit_ns(c)) for c in self.numeric_clocks}
        self.clocks.update({c: _Clock(None) for c in self.temporal})
        #: the clock whose times :meth:`pieces` gives (the first candidate; :meth:`finish` says whether it is one)
        self.assumed = next(iter(self.clocks), None)

    def _batches(self, only: str | None = None
                 ) -> Iterator[tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.int64]]]]:
        """The pieces' numeric columns and timestamp / duration columns as ns; ``only``: that column alone."""
        from streamid.logs.arrow_tables import Refused, csv_batches, float_pieces

        names = self.names if only is None else [c for c in self.names if c == only]
        temporal = self.temporal if only is None else [c for c in self.temporal if c == only]
        try:
            if self.csv is not None:
                lay = self.csv
                wanted = lay.wanted if only is None else [only]
                source = lay.source(Path(self.path))
                try:
                    yield from float_pieces(csv_batches(source, lay.header, lay.header_no, wanted,
                                                        **lay.arrow_options()), wanted)
                finally:
                    if not isinstance(source, str):
                        source.close()
            else:
                yield from float_pieces(self.batches([*names, *temporal]), names, temporal)
        except Refused as exc:
            raise NotStreamable(str(exc)) from None

    def _column(self, name: str) -> Iterator[NDArray[Any]]:
        """The clock candidate ``name``'s values again, a piece at a time (:meth:`_Clock.period`)."""
        for cols, times in self._batches(name):
            yield times[name] if name in times else cols[name]

    def pieces(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64] | None]]:
        """``(u, y, t_ns)`` of each piece: the inputs (rows, n_inputs), the output, and the times of
        :attr:`assumed` (None without a candidate); the rows ``handle_missing`` keeps, missing values filled
        (``--fill``), once known (a run of rows with a missing value is held until a complete row follows)."""
        for cols, times in self._batches():
            used = {c: cols[c] for c in self.used}
            self.stats.add(used)
            t = None
            for c, clock in self.clocks.items():
                tc = clock.add(times[c] if c in times else cols[c])
                t = tc if c == self.assumed else t
            self.rows += len(used[self.output])
            try:
                kept = self.gaps.feed(used, t)
            except LongGap as exc:
                raise LongRun(str(exc)) from None
            for part, tp in kept:
                if len(part[self.output]):
                    yield np.column_stack([part[c] for c in self.inputs]), part[self.output], tp

    def finish(self, allow_time_input: bool) -> tuple[list[str], dict[str, Any], int | None, str | None]:
        """After :meth:`pieces`: the notes, ``info`` (as ``load_record``'s), the period and the clock's name."""
        notes = self.stats.judge(allow_time_input)
        lines = None if self.csv is None else RowLines(Path(self.path), self.csv.enc, self.csv.header_no, self.rows)
        gap_notes, counts = self.gaps.finish(self.path, lines)
        notes += gap_notes
        clock, period = None, None
        for c, ck in self.clocks.items():
            if c in self.numeric_clocks and (p := ck.period(partial(self._column, c))) is not None:
                clock, period = c, p
                break
        if clock is None:
            for c in self.temporal:
                if (p := self.clocks[c].period(partial(self._column, c))) is not None:
                    clock, period = c, p
                    break
        info = dict(self.info)
        if clock is not None:
            info["clock"] = clock
        info["rows"] = self.rows
        info["missing"] = counts
        return notes, info, period, clock
