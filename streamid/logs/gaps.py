"""Missing and infinite values of a record read a piece at a time (:mod:`streamid.logs.pieces`):
:func:`~streamid.logs.columns.handle_missing`'s rules, words and figures, in memory bounded by the piece.

:class:`GapStream` takes the used columns' raw rows in order (:meth:`~GapStream.feed`) and gives the rows
``handle_missing`` keeps, in order, as soon as they are known: a row with a missing value (NaN) in a used column
is held until the next row without one says whether its run is inside the record (``--fill`` fills it, ``--drop``
leaves it out and counts the place) or at its end (cut). ``--fill`` interpolates a run between the rows on each
side of it (the last and next rows with every value; each column between its own neighbouring values, which lie
in that span): ``np.interp`` on that span gives the whole column's bits (its result depends only on the two
neighbours and integer differences of positions). :meth:`~GapStream.finish` raises ``handle_missing``'s errors in
its order (an infinite value, the missing values under ``"error"``, no complete row, ``--drop`` at more than one
place per 100 rows) and returns its notes and counts.

Held: the first five rows with a missing value and the first five places (for the messages), each column's
longest filled run, and under ``--fill`` the values of the run being held, at most :data:`MAX_GAP_ROWS` rows: a
longer run is forgotten, which is right when the record ends in it (cut) and raises :class:`LongGap` when a row
with every value follows it (the caller reads the file whole). Under ``"error"`` (once a missing value is seen) or
after an infinite value nothing more is given: the end raises.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.logs.columns import (_SHOW, Lines, _runs, _span, cut_note, drop_limit, drop_note, drop_refusal,
                                   fill_note, inf_error, missing_error, no_row_error, row_label)

__all__ = ["MAX_GAP_ROWS", "GapStream", "LongGap"]

#: Rows of one run of missing values ``--fill`` holds while it waits for the run's end (65,536: one chunk).
MAX_GAP_ROWS = 1 << 16

Piece = tuple[dict[str, NDArray[np.float64]], NDArray[np.int64] | None]


class LongGap(Exception):
    """A run of rows with a missing value longer than :data:`MAX_GAP_ROWS` inside the record under ``--fill``."""


class GapStream:
    """``handle_missing(where, columns, policy, lines)`` over ``names``' rows given a piece at a time (module
    docstring). Each piece's times ``t`` (or None) follow its kept rows."""

    def __init__(self, names: Sequence[str], policy: str) -> None:
        self.names, self.policy = list(names), policy
        self.n = 0  # rows seen
        self.inf: dict[str, tuple[int, float]] = {}  # each column's first infinite value (row, value)
        self.bad = 0  # rows with a missing value
        self.shown: list[tuple[int, list[str]]] = []  # the first of them, with the columns missing
        self.first: int | None = None  # the first row with every value
        self.last = -1  # the last one so far
        self.anchor: dict[str, NDArray[np.float64]] = {}  # its values (--fill)
        self.gap_start, self.gap_rows, self.gap_lost = 0, 0, False  # the run held after it
        self.gap: list[Piece] = []  # its rows (--fill; forgotten past MAX_GAP_ROWS)
        self.inner = 0  # rows with a missing value between the first and the last complete rows
        self.places = 0  # runs of them
        self.runs: list[tuple[int, int]] = []  # the first of those runs (first, last row)
        self.filled = 0
        self.longest: dict[str, tuple[int, int, int]] = {}  # each column's first longest filled run (length, a, b)

    @property
    def doomed(self) -> bool:
        """The end will raise (an infinite value, or a missing one under ``"error"``)."""
        return bool(self.inf) or (self.policy == "error" and self.bad > 0)

    def feed(self, cols: dict[str, NDArray[np.float64]], t: NDArray[np.int64] | None) -> list[Piece]:
        """The next raw rows of every column of ``names``; the rows now known to be kept (none, or pieces)."""
        k = len(cols[self.names[0]])
        base = self.n
        self.n += k
        if not k:
            return []
        for c in self.names:
            if c not in self.inf and (w := np.flatnonzero(np.isinf(cols[c]))).size:
                self.inf[c] = (base + int(w[0]), float(cols[c][w[0]]))
        miss = np.column_stack([np.isnan(cols[c]) for c in self.names])
        badrow: NDArray[np.bool_] = np.asarray(miss.any(axis=1))
        bad = np.flatnonzero(badrow)
        self.bad += int(bad.size)
        for i in bad[: max(0, _SHOW - len(self.shown))]:
            self.shown.append((base + int(i), [c for j, c in enumerate(self.names) if miss[i, j]]))
        if self.doomed:
            return []
        ok = np.flatnonzero(~badrow)
        if not ok.size:
            self._hold(cols, t, 0, k, base)
            return []
        i0, i1 = int(ok[0]), int(ok[-1])
        out: list[Piece] = []
        if self.first is None:
            self.first = base + i0  # the rows before: cut (with those held, none: nothing is held before it)
        elif self.gap_rows or i0:
            out += self._close(cols, t, i0, base)
        inside = bad[(bad > i0) & (bad < i1)]
        seg = {c: v[i0 : i1 + 1] for c, v in cols.items()}
        ts = None if t is None else t[i0 : i1 + 1]
        if inside.size:
            self.inner += int(inside.size)
            if self.policy == "drop":
                for a, b in _runs(inside + base):
                    self._place(a, b)
                keep = ~badrow[i0 : i1 + 1]
                seg = {c: v[keep] for c, v in seg.items()}
                ts = None if ts is None else ts[keep]
            else:
                seg = {c: self._fill(c, v, base + i0) for c, v in seg.items()}
        out.append((seg, ts))
        self.last = base + i1
        self.anchor = {c: v[i1 : i1 + 1].copy() for c, v in cols.items()}
        self._hold(cols, t, i1 + 1, k, base)
        return out

    def _place(self, a: int, b: int) -> None:
        self.places += 1
        if len(self.runs) < _SHOW:
            self.runs.append((a, b))

    def _fill(self, c: str, v: NDArray[np.float64], at: int) -> NDArray[np.float64]:
        """``v`` (rows from ``at``, complete rows at both ends) with its holes interpolated as ``handle_missing``
        interpolates them, counted (filled values, each column's longest run)."""
        holes = np.flatnonzero(np.isnan(v))
        if not holes.size:
            return v
        part = v.copy()
        have = np.flatnonzero(~np.isnan(v))
        part[holes] = np.interp(holes, have, part[have])
        self.filled += int(holes.size)
        for a, b in _runs(holes + at):
            if b - a + 1 > self.longest.get(c, (0, 0, 0))[0]:
                self.longest[c] = (b - a + 1, a, b)
        return part

    def _hold(self, cols: dict[str, NDArray[np.float64]], t: NDArray[np.int64] | None, a: int, b: int,
              base: int) -> None:
        """Rows ``a..b-1`` of the piece have a missing value: held until a complete row follows (or the end)."""
        if a >= b or self.first is None:
            return  # none, or before the first complete row (cut)
        if not self.gap_rows:
            self.gap_start = base + a
        self.gap_rows += b - a
        if self.policy != "fill" or self.gap_lost:
            return
        if self.gap_rows > MAX_GAP_ROWS:
            self.gap, self.gap_lost = [], True  # kept only if the record ends in it
            return
        self.gap.append(({c: v[a:b].copy() for c, v in cols.items()}, None if t is None else t[a:b].copy()))

    def _close(self, cols: dict[str, NDArray[np.float64]], t: NDArray[np.int64] | None, i0: int,
               base: int) -> list[Piece]:
        """The held run and the piece's rows before ``i0`` (its first complete row) end: one place inside."""
        a = self.gap_start if self.gap_rows else base
        rows = self.gap_rows + i0
        self.inner += rows
        held, self.gap, self.gap_rows = self.gap, [], 0
        if self.policy == "drop":
            self._place(a, a + rows - 1)
            return []
        if self.gap_lost or rows > MAX_GAP_ROWS:
            self.gap_lost = False
            raise LongGap(f"--fill meets a run of {rows} rows with a missing value (rows {a + 1}-{a + rows}), longer "
                          f"than the {MAX_GAP_ROWS} held while a file is read a piece at a time")
        out: dict[str, NDArray[np.float64]] = {}
        for c in self.names:
            span = np.concatenate([self.anchor[c], *(g[0][c] for g in held), cols[c][: i0 + 1]])
            out[c] = self._fill(c, span, a - 1)[1:-1]
        ts = None if t is None else np.concatenate([*(g[1] for g in held if g[1] is not None), t[:i0]])
        return [(out, ts)]

    def finish(self, where: str, lines: Lines | None) -> tuple[list[str], dict[str, Any]]:
        """After the last piece: ``handle_missing``'s notes and ``load_record``'s ``info["missing"]``; its
        errors (:class:`~streamid.errors.DataError`) raised in its order."""
        for c in self.names:
            if c in self.inf:
                row, value = self.inf[c]
                raise inf_error(where, c, row_label(row, lines), value)
        counts = {"policy": self.policy, "rows_with_missing": self.bad, "rows_dropped": 0, "values_filled": 0,
                  "places_spacing_broken": 0}
        if not self.bad:
            return [], counts
        if self.policy == "error":
            raise missing_error(where, self.shown, self.bad, self.n, lines)
        if self.first is None:
            raise no_row_error(where, self.names)
        notes = []
        if self.first or self.last < self.n - 1:
            notes.append(cut_note(self.first, self.n - 1 - self.last))
        if self.policy == "drop":
            limit = drop_limit(self.n)
            if self.places > limit:
                raise drop_refusal(where, self.runs, self.places, limit, lines)
            if self.places:
                notes.append(drop_note(self.inner, self.runs, self.places, lines))
            counts.update(rows_dropped=self.bad, places_spacing_broken=self.places)
            return notes, counts
        if self.filled:
            best = (0, "")
            for c in self.names:
                if c in self.longest and self.longest[c][0] > best[0]:
                    n_run, a, b = self.longest[c]
                    best = (n_run, f"{c!r}, {_span(a, b, lines)}")
            notes.append(fill_note(self.filled, self.inner, best))
        counts.update(rows_dropped=self.n - (self.last - self.first + 1), values_filled=self.filled)
        return notes, counts
