"""Checks and repairs of the columns chosen for an identification: what a user's own file gets wrong.

:func:`check_columns`
    an input that is the output (by name or by value), a repeated input, a constant
    input, and an input that only ever increases or decreases (a time column, most
    likely): an error unless ``allow_time_input``, then a warning.
:func:`handle_missing`
    rows with a missing value (NaN) in the columns used: ``"error"`` (default) names
    the first rows and the two ways out; ``"drop"`` leaves the rows out; ``"fill"``
    interpolates linearly.  Both cut missing rows at the start and the end of the
    record (that keeps the sample spacing).  ``"drop"`` of rows inside the record
    joins samples that were not adjacent: a warning says how many places, and more
    than one place per 100 rows (at least 1 allowed) is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.logs.csv_table import time_unit_ns

__all__ = ["MISSING_POLICIES", "Cleaned", "ColumnStats", "check_columns", "handle_missing", "row_label"]

MISSING_POLICIES = ("error", "drop", "fill")


class Lines(Protocol):
    """The file line of row ``i`` (``lines[i]``): an array, or :class:`streamid.logs.csv_table.RowLines`."""

    def __getitem__(self, i: int, /) -> Any: ...


_SHOW = 5  # rows named in a message


def row_label(i: int, lines: Lines | None) -> str:
    """Where row ``i`` (0-based) is in the file: ``line N`` of a text file, else ``sample N`` (1-based)."""
    return f"line {int(lines[i])}" if lines is not None else f"sample {i + 1}"


def _monotonic(steps: int, up: int, down: int) -> str | None:
    """'increasing'/'decreasing' when the finite values never go the other way and move at >= 90 % of steps, from
    the count of steps between consecutive finite values, those up and those down.

    Judged on 10 samples or more (a random column of 10 is monotonic by chance with probability 2/10! = 6e-7).
    """
    if steps + 1 < 10:
        return None
    for moved, back, word in ((up, down, "increasing"), (down, up, "decreasing")):
        if not back and moved / steps >= 0.9:
            return word
    return None


class ColumnStats:
    """What :func:`check_columns` judges, summed over a file read a piece at a time (:meth:`add` each piece's
    columns, in order): per input whether it equals the output, its first finite value and whether every one
    equals it, and the steps between its consecutive finite values (up, down)."""

    def __init__(self, inputs: Sequence[str], output: str) -> None:
        self.inputs, self.output = list(inputs), output
        self.same = dict.fromkeys(self.inputs, True)
        self.first: dict[str, float | None] = dict.fromkeys(self.inputs)
        self.constant = dict.fromkeys(self.inputs, True)
        self.last: dict[str, float | None] = dict.fromkeys(self.inputs)
        self.steps = {c: [0, 0, 0] for c in self.inputs}  # steps, up, down

    def add(self, columns: dict[str, NDArray[np.float64]]) -> None:
        y = columns[self.output]
        for name in self.inputs:
            u = columns[name]
            self.same[name] = self.same[name] and u.shape == y.shape and bool(np.array_equal(u, y, equal_nan=True))
            f = u[np.isfinite(u)]
            if not f.size:
                continue
            if self.first[name] is None:
                self.first[name] = float(f[0])
            self.constant[name] = self.constant[name] and bool(np.all(f == self.first[name]))
            last = self.last[name]
            d = np.diff(f) if last is None else np.diff(np.concatenate([[last], f]))
            st = self.steps[name]
            st[0] += int(d.size)
            st[1] += int(np.count_nonzero(d > 0))
            st[2] += int(np.count_nonzero(d < 0))
            self.last[name] = float(f[-1])

    def judge(self, allow_time_input: bool = False) -> list[str]:
        """:func:`check_columns`' verdict: its errors raised, its warnings returned."""
        inputs, output = self.inputs, self.output
        if output in inputs:
            raise DataError(
                f"--input {output}: the column {output!r} is the --output too; a model of {output} from its own present "
                f"value would be trivial (its past values are regressors already, up to --max-lag-y); choose other inputs"
            )
        seen: set[str] = set()
        for name in inputs:
            if name in seen:
                raise DataError(f"--input {name} is given twice; give each input column once")
            seen.add(name)
        warnings: list[str] = []
        for name in inputs:
            if self.same[name]:
                raise DataError(
                    f"--input {name}: the column {name!r} holds exactly the values of the output {output!r}; a model "
                    f"of {output} from itself would be trivial; choose other inputs"
                )
            first = self.first[name]
            if first is not None and self.constant[name]:
                raise DataError(
                    f"--input {name}: the column {name!r} is constant (every value {first!r}); it carries nothing "
                    "to identify from; choose inputs that vary"
                )
            steps = self.steps[name]
            trend = _monotonic(*steps)
            if trend is not None:
                msg = (
                    f"--input {name}: the column {name!r} is {trend} over all its {steps[0] + 1} samples (a time "
                    f"column?); a model of {output} from it meets, on the validation part and later, values it never saw"
                )
                if not allow_time_input:
                    raise DataError(msg + "; pass --allow-time-input to use it anyway")
                warnings.append(msg + " (used, --allow-time-input)")
            elif time_unit_ns(name) is not None:
                warnings.append(f"--input {name}: the column {name!r} is named like a time; it is used as an input signal")
        return warnings


def check_columns(
    where: str,
    inputs: Sequence[str],
    output: str,
    columns: dict[str, NDArray[np.float64]],
    *,
    allow_time_input: bool = False,
) -> list[str]:
    """Refuse inputs a model cannot be made of; return the warnings (see the module's rules; :class:`ColumnStats`
    judges a file read a piece at a time the same way).

    Raises
    ------
    DataError
        Naming the column, what is wrong and what to do.
    """
    stats = ColumnStats(inputs, output)
    if output not in inputs and len(set(inputs)) == len(inputs):
        stats.add(columns)
    return stats.judge(allow_time_input)


@dataclass(frozen=True)
class Cleaned:
    """The used columns after :func:`handle_missing`, and what was done."""

    columns: dict[str, NDArray[np.float64]]
    keep: NDArray[np.int64]  # indices of the file's rows kept, in order
    notes: tuple[str, ...]
    rows_missing: int  # rows that had a missing value in a used column
    dropped: int  # rows left out (cut at the ends, or dropped inside)
    filled: int  # cells filled by interpolation
    gaps: int  # places inside the record where --drop joined samples that were not adjacent


def _runs(idx: NDArray[np.int64]) -> list[tuple[int, int]]:
    """Runs of consecutive indices as (first, last)."""
    if idx.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(idx) != 1)
    starts = np.concatenate([[idx[0]], idx[cuts + 1]])
    ends = np.concatenate([idx[cuts], [idx[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def _span(a: int, b: int, lines: Lines | None) -> str:
    return row_label(a, lines) if a == b else f"{row_label(a, lines)}-{int(lines[b]) if lines is not None else b + 1}"


def inf_error(where: str, name: str, label: str, value: float) -> DataError:
    """The error for an infinite ``value`` in column ``name`` at ``label`` (:func:`row_label`)."""
    return DataError(f"{where}: column {name!r}, {label}: {value!r} is not a finite number; only numbers (or missing "
                     "values: empty, NaN) are accepted")


def missing_error(where: str, shown: Sequence[tuple[int, Sequence[str]]], n_bad: int, n: int,
                  lines: Lines | None) -> DataError:
    """The error for ``n_bad`` of ``n`` rows with a missing value (policy ``"error"``); ``shown``: the first
    :data:`_SHOW` of them (row, the columns missing there)."""
    rows = "; ".join(f"{row_label(i, lines)} ({', '.join(cols)})" for i, cols in shown[:_SHOW])
    more = f"; and {n_bad - _SHOW} more" if n_bad > _SHOW else ""
    return DataError(
        f"{where}: {n_bad} row{'s' if n_bad > 1 else ''} of {n} {'have' if n_bad > 1 else 'has'} a missing value (empty, NaN, NA) in the "
        f"columns used: {rows}{more}. Pass --fill to fill them by linear interpolation between the neighbouring "
        "samples of each column, or --drop to leave those rows out (rows at the start and end are simply cut)"
    )


def no_row_error(where: str, names: Sequence[str]) -> DataError:
    return DataError(f"{where}: no row has a number in every column used ({', '.join(names)})")


def cut_note(first: int, end: int) -> str:
    """The note for ``first`` rows cut at the start and ``end`` at the end."""
    return (f"cut {first} row{'s' if first != 1 else ''} at the start and {end} at the end of the record "
            "(a missing value in a column used); the sample spacing is kept")


def drop_limit(n: int) -> int:
    """The places inside a record of ``n`` rows where ``--drop`` may join samples: one per 100 rows, at least 1."""
    return max(1, n // 100)


def drop_refusal(where: str, runs: Sequence[tuple[int, int]], n_runs: int, limit: int, lines: Lines | None) -> DataError:
    """``--drop`` refused: ``n_runs`` places (``runs``: the first :data:`_SHOW`) over ``limit``."""
    return DataError(
        f"{where}: --drop would join samples that were not adjacent at {n_runs} places inside the record "
        f"(first: {'; '.join(_span(a, b, lines) for a, b in runs[:_SHOW])}); at most one place per 100 rows "
        f"({limit} here) is accepted, as the lagged values after each place mix both sides of it. Use --fill "
        "(linear interpolation between the neighbouring samples), or clean the file"
    )


def drop_note(inner: int, runs: Sequence[tuple[int, int]], n_runs: int, lines: Lines | None) -> str:
    """``--drop``'s note: ``inner`` rows left out inside the record at ``n_runs`` places (``runs``: the first)."""
    return (f"--drop: left out {inner} row{'s' if inner > 1 else ''} inside the record "
            f"({'; '.join(_span(a, b, lines) for a, b in runs[:_SHOW])}{' ...' if n_runs > _SHOW else ''}): "
            f"the sample spacing is broken at {n_runs} place{'s' if n_runs > 1 else ''} (up to max-lag "
            "samples after each see lagged values from before it); --fill keeps the spacing")


def fill_note(filled: int, inner: int, longest: tuple[int, str]) -> str:
    """``--fill``'s note: ``filled`` values in ``inner`` rows, the longest run (its length, where)."""
    return (f"--fill: filled {filled} missing value{'s' if filled > 1 else ''} in {inner} row"
            f"{'s' if inner > 1 else ''} by linear interpolation between the neighbouring samples of each column "
            f"(longest run {longest[0]} sample{'s' if longest[0] > 1 else ''}: {longest[1]})")


def handle_missing(
    where: str,
    columns: dict[str, NDArray[np.float64]],
    policy: str,
    lines: Lines | None = None,
) -> Cleaned:
    """Apply the missing-value ``policy`` (``"error"``, ``"drop"``, ``"fill"``) to the used ``columns``
    (:class:`streamid.logs.gaps.GapStream`: the same a piece at a time).

    ``lines``: the file line of every row (text files), used to name rows.
    """
    if policy not in MISSING_POLICIES:
        raise DataError(f"missing must be one of {MISSING_POLICIES}; got {policy!r}")
    names = list(columns)
    n = len(next(iter(columns.values())))
    for name, v in columns.items():
        inf = np.flatnonzero(np.isinf(v))
        if inf.size:
            raise inf_error(where, name, row_label(int(inf[0]), lines), float(v[inf[0]]))
    miss = np.column_stack([np.isnan(columns[c]) for c in names])
    bad = np.flatnonzero(miss.any(axis=1))
    every = np.arange(n, dtype=np.int64)
    if bad.size == 0:
        return Cleaned(dict(columns), every, (), 0, 0, 0, 0)
    if policy == "error":
        shown = [(int(i), [c for j, c in enumerate(names) if miss[i, j]]) for i in bad[:_SHOW]]
        raise missing_error(where, shown, int(bad.size), n, lines)
    ok: NDArray[np.bool_] = np.asarray(~miss.any(axis=1))
    if not ok.any():
        raise no_row_error(where, names)
    first, last = int(np.argmax(ok)), int(n - 1 - np.argmax(ok[::-1]))
    notes: list[str] = []
    if first or last < n - 1:
        notes.append(cut_note(first, n - 1 - last))
    inner = bad[(bad > first) & (bad < last)]
    runs = _runs(inner)
    if policy == "drop":
        limit = drop_limit(n)
        if len(runs) > limit:
            raise drop_refusal(where, runs, len(runs), limit, lines)
        keep = every[first : last + 1][ok[first : last + 1]]
        if runs:
            notes.append(drop_note(int(inner.size), runs, len(runs), lines))
        cols = {c: v[keep] for c, v in columns.items()}
        return Cleaned(cols, keep, tuple(notes), int(bad.size), n - keep.size, 0, len(runs))
    keep = every[first : last + 1]
    cols = {}
    filled, longest = 0, (0, "")
    for c, v in columns.items():
        part = v[keep].copy()
        holes = np.flatnonzero(np.isnan(part))
        if holes.size:
            have = np.flatnonzero(~np.isnan(part))
            part[holes] = np.interp(holes, have, part[have])
            filled += int(holes.size)
            for a, b in _runs(holes + first):
                if b - a + 1 > longest[0]:
                    longest = (b - a + 1, f"{c!r}, {_span(a, b, lines)}")
        cols[c] = part
    if filled:
        notes.append(fill_note(filled, int(inner.size), longest))
    return Cleaned(cols, keep, tuple(notes), int(bad.size), n - keep.size, filled, 0)
