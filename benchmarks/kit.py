"""Small toolkit behind ``streamid bench``: measurements, medians, the machine, the table.

Benchmark providers are plain callables ``provider(options) -> Iterable[Measurement]``.
streamid's own providers live next to the code they measure
(``benchmarks.engine_cases``, ``benchmarks.daemon_cases``); the packages around
streamid (``replay``, ``recorders``) register theirs in the ``streamid.benchmarks``
entry-point group, so streamid never imports them.

Every figure is a median over repeated runs; the spread (min, max) and the
number of runs are kept beside it so that a reader can judge the noise.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "BenchOptions",
    "Measurement",
    "machine_description",
    "measure",
    "summarise",
    "format_table",
]


@dataclass(frozen=True)
class BenchOptions:
    """What the user asked of ``streamid bench``.

    Attributes
    ----------
    repeat : int
        Number of repetitions a figure is the median of.
    quick : bool
        Smaller problem sizes and fewer repetitions (a smoke run, not for quoting).
    peers : bool
        Also fit the same data with the peer tools (SysIdentPy) in the same run.
    seed : int
        First seed; repetition ``i`` uses ``seed + i``.
    systems : tuple of str
        ``--suite`` only: the systems to run (empty: all).
    """

    repeat: int = 5
    quick: bool = False
    peers: bool = False
    seed: int = 0
    systems: tuple[str, ...] = ()


@dataclass(frozen=True)
class Measurement:
    """One line of the benchmark table.

    ``values`` holds the figure of every repetition; the table shows their
    median, and min/max where there is more than one.
    """

    section: str
    case: str
    metric: str
    unit: str
    values: tuple[float, ...]
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def median(self) -> float:
        return float(statistics.median(self.values))

    @property
    def low(self) -> float:
        return float(min(self.values))

    @property
    def high(self) -> float:
        return float(max(self.values))

    def to_dict(self) -> dict[str, Any]:
        return {
            "section": self.section,
            "case": self.case,
            "metric": self.metric,
            "unit": self.unit,
            "median": self.median,
            "min": self.low,
            "max": self.high,
            "n": len(self.values),
            "values": list(self.values),
            "note": self.note,
            **({"extra": self.extra} if self.extra else {}),
        }


def measure(fn: Callable[[int], float], repeat: int, seed: int = 0) -> tuple[float, ...]:
    """Call ``fn(seed + i)`` ``repeat`` times and return the figures it returns."""
    if repeat < 1:
        raise ValueError(f"repeat must be a whole number >= 1, got {repeat!r}")
    return tuple(float(fn(seed + i)) for i in range(repeat))


def summarise(
    section: str,
    case: str,
    metric: str,
    unit: str,
    values: Sequence[float],
    note: str = "",
) -> Measurement:
    return Measurement(section, case, metric, unit, tuple(float(v) for v in values), note)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _memory_gib() -> float | None:
    try:
        with open("/proc/meminfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 1024**2
    except OSError:
        pass
    return None


def machine_description() -> dict[str, str]:
    """The facts about this machine that a benchmark figure depends on."""
    import numpy as np
    import scipy

    mem = _memory_gib()
    desc = {
        "date": time.strftime("%Y-%m-%d"),
        "cpu": _cpu_model(),
        "cores": str(os.cpu_count()),
        "memory": f"{mem:.0f} GiB" if mem is not None else "unknown",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "os": f"{platform.system()} {platform.release()}",
    }
    try:
        from threadpoolctl import threadpool_info

        blas = [f"{i['internal_api']} {i['version']}" for i in threadpool_info() if i["user_api"] == "blas"]
        if blas:
            desc["blas"] = ", ".join(blas)
    except Exception:  # pragma: no cover - informational only
        pass
    return desc


def _fmt(value: float) -> str:
    if value != value:  # NaN
        return "nan"
    a = abs(value)
    if a == 0:
        return "0"
    if a >= 1e6:
        return f"{value:,.0f}"
    if a >= 100:
        return f"{value:.1f}"
    if a >= 0.995 and a < 1.0 + 1e-12:
        return f"{value:.5f}"
    if a >= 1:
        return f"{value:.3f}"
    if a >= 0.9:
        return f"{value:.5f}"
    if a >= 1e-3:
        return f"{value:.4f}"
    return f"{value:.3g}"


def format_table(rows: Iterable[Measurement]) -> str:
    """A plain-text (also valid Markdown) table of the measurements."""
    header = ("section", "case", "metric", "median", "min", "max", "n", "unit", "note")
    lines = [header]
    for m in rows:
        many = len(m.values) > 1
        lines.append(
            (
                m.section,
                m.case,
                m.metric,
                _fmt(m.median),
                _fmt(m.low) if many else "",
                _fmt(m.high) if many else "",
                str(len(m.values)),
                m.unit,
                m.note,
            )
        )
    widths = [max(len(r[i]) for r in lines) for i in range(len(header))]
    out = []
    for k, r in enumerate(lines):
        out.append("| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |")
        if k == 0:
            out.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(out)
