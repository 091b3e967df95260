"""Signals recorded each at its own times (MDF channel groups, ROS 2 topics), put on one sample grid.

The rule (the same for files and for live ROS 2 topics)
-------------------------------------------------------
* **The grid is the output's own timestamps.** A NARX model counts lags in samples of the output, so the
  output keeps every sample it has, at the time it was recorded; nothing is invented on it.
* **Each input is zero-order held**: its value at a grid time is its latest sample at or before that time.
  Held, not linearly interpolated, because holding is causal: an interpolated value at time ``t`` mixes in the
  input's next sample, recorded after ``t``, so a model would see up to one input period of the future (and a
  command, which a device holds until the next one, is read as the device saw it).  An input faster than the
  output is not averaged: its latest sample is taken (a note names both rates).
* **Cut, never extrapolated**: the grid starts at the first output time at which every input has a sample
  and ends at the last output time before an input's last sample plus one of its own periods (a note says how
  many samples were cut).
* **Refused, with the rates named**: fewer than :data:`MIN_SAMPLES` grid samples in the common time span; an
  output whose times do not increase; an output whose steps leave ``[0.5, 1.5]`` times its median step at
  more than one place per 100 samples (the same limit as ``--drop``'s: a lag there would span another time);
  at fewer places the record is used and a note names them.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.logs.table import SHOWN_NAMES, Table

__all__ = ["MIN_SAMPLES", "SHOWN_NAMES", "Signal", "names_line", "needs_library", "on_output_grid", "rate_text",
           "held_at", "why_text"]

#: Fewest samples a record on the grid may hold.
MIN_SAMPLES = 10


@dataclass(frozen=True)
class Signal:
    """One signal as recorded: its sample times (int64 ns, non-decreasing) and values (float64)."""

    name: str
    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]

    def period_ns(self) -> int:
        """The median step between its samples (0 with fewer than two)."""
        return int(np.median(np.diff(self.t_ns))) if self.t_ns.size > 1 else 0


def names_line(names: Sequence[str], what: str = "signals") -> str:
    """``"N signals: a, b, ... (first 20)"`` of what a file holds, for a one-line message."""
    shown = ", ".join(names[:SHOWN_NAMES])
    more = f" (the first {SHOWN_NAMES} shown)" if len(names) > SHOWN_NAMES else ""
    return f"it holds {len(names)} {what}{more}: {shown or 'none'}"


def needs_library(module: str, what: str) -> DataError:
    """The error for a missing optional reader: which library, and the extra that installs it."""
    return DataError(f"reading {what} needs the Python library {module!r}, which is not installed: it comes with "
                     "streamid's extra 'lab' (pip install '.[lab]' in streamid's source tree, as the README's "
                     f"journey 4 says; pip install 'streamid[lab]' from a package index) or alone: pip install {module}")


def why_text(exc: BaseException, limit: int = 200) -> str:
    """A foreign library's exception as a short clause of a one-line message: its kind and its text on one line
    (a YAML or HDF5 error spans several; a reader's repr of its own buffer is not the user's file name)."""
    text = re.sub(r"'?<mmap\.mmap [^>]*>'?", "the file", " ".join(str(exc).split()))
    return f"{type(exc).__name__}: {text[:limit]}" if text else type(exc).__name__


def rate_text(period_ns: int) -> str:
    """A rate in words, from a period: ``100 Hz (every 10 ms)``."""
    if period_ns <= 0:
        return "a single sample"
    return f"{1e9 / period_ns:.6g} Hz (every {period_ns / 1e6:.6g} ms)"


def held_at(t_ns: NDArray[np.int64], values: NDArray[np.float64], grid_ns: NDArray[np.int64]) -> NDArray[np.float64]:
    """Zero-order hold: at each grid time the latest value at or before it (NaN before the first sample)."""
    idx = np.searchsorted(t_ns, grid_ns, side="right") - 1
    out = np.full(grid_ns.shape, np.nan)
    ok = idx >= 0
    out[ok] = values[idx[ok]]
    return out


def _span_text(s: Signal) -> str:
    if s.t_ns.size == 0:
        return f"{s.name} has no samples"
    return (f"{s.name} spans {s.t_ns[0] / 1e9:.6g}-{s.t_ns[-1] / 1e9:.6g} s at {rate_text(s.period_ns())}")


def _check_grid(where: str, out: Signal, grid: NDArray[np.int64]) -> list[str]:
    steps = np.diff(grid)
    if steps.size and not bool(np.all(steps > 0)):
        i = int(np.argmin(steps > 0))
        raise DataError(f"{where}: the output {out.name}'s times must increase (they are the sample grid); "
                        f"sample {i + 2} at {int(grid[i + 1])} ns follows {int(grid[i])} ns")
    period = int(np.median(steps))
    odd = np.flatnonzero((steps < period // 2) | (steps > period + period // 2))
    if odd.size == 0:
        return []
    limit = max(1, grid.size // 100)
    worst = int(odd[np.argmax(np.abs(steps[odd] - period))])
    said = (f"{odd.size} step{'s' if odd.size > 1 else ''} of the output {out.name} (sampled at "
            f"{rate_text(period)}) leave 0.5-1.5 times its median step (the largest: {steps[worst] / 1e6:.6g} ms "
            f"at {grid[worst] / 1e9:.6g} s)")
    if odd.size > limit:
        raise DataError(f"{where}: {said}; at most one place per 100 samples ({limit} here) is accepted, as the "
                        "output's own times are the sample grid and a lag across such a step spans another time: "
                        "choose an output sampled at a steady rate")
    return [said + ": used, the lags across those steps span another time"]


def on_output_grid(where: str, inputs: Sequence[Signal], output: Signal, meta: dict[str, object]) -> Table:
    """The inputs zero-order held on the output's own timestamps (the module's rule), as a :class:`Table`.

    Raises
    ------
    DataError
        The rule's refusals, naming the signals' rates and spans.
    """
    if output.t_ns.size < 2:
        raise DataError(f"{where}: the output {output.name} has {output.t_ns.size} sample(s); its own timestamps "
                        f"are the sample grid and it needs at least {MIN_SAMPLES}")
    grid = output.t_ns
    notes = _check_grid(where, output, grid)
    lo = max([int(s.t_ns[0]) for s in inputs if s.t_ns.size] + [int(grid[0])])
    hi = min([int(s.t_ns[-1]) + s.period_ns() for s in inputs if s.t_ns.size] + [int(grid[-1])])
    keep = (grid >= lo) & (grid <= hi)
    n = int(keep.sum())
    if n < MIN_SAMPLES or any(s.t_ns.size == 0 for s in inputs):
        raise DataError(f"{where}: the signals share {n} sample(s) of the output's grid, at least {MIN_SAMPLES} are "
                        f"needed: {'; '.join(_span_text(s) for s in (*inputs, output))}")
    cut = grid.size - n
    t = grid[keep]
    period = int(np.median(np.diff(t)))
    columns: dict[str, NDArray[np.float64]] = {}
    for s in inputs:
        columns[s.name] = held_at(s.t_ns, s.values, t)
        p = s.period_ns()
        if 0 < p < period // 2:
            notes.append(f"the input {s.name} ({1e9 / p:.6g} Hz) is faster than the output {output.name} "
                         f"({1e9 / period:.6g} Hz): its latest sample at each output time is used, not an average "
                         "(low-pass it first if it carries content above half the output's rate)")
    columns[output.name] = np.asarray(output.values[keep], dtype=np.float64)
    if cut:
        notes.append(f"cut {cut} of the output's {grid.size} samples outside the time span every signal covers "
                     f"({lo / 1e9:.6g}-{hi / 1e9:.6g} s)")
    rates = {s.name: rate_text(s.period_ns()) for s in (*inputs, output)}
    info = {**meta, "clock": output.name, "resample": "inputs zero-order held on the "
            "output's timestamps", "rates": rates, "notes": tuple(notes)}
    return Table(where, columns, t_ns=t.astype(np.int64), period_ns=period, meta=info)
