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
from pathlib import Path
from typing import Any

__all__ = [
    "BenchOptions",
    "Measurement",
    "machine_description",
    "measure",
    "summarise",
    "format_table",
    "PeakRun",
    "run_with_peak",
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


def _hwm_kib(pid: int) -> int:
    """The process's peak resident memory so far (``VmHWM`` of /proc/<pid>/status, KiB; 0 when gone or a zombie)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def _descendants(pid: int) -> list[int]:
    """Every process under ``pid`` (its children's children too), from /proc's ``children`` lists."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                kids = [int(k) for k in (task / "children").read_text().split()]
                out += kids
                todo += kids
        except (OSError, ValueError):
            pass
    return out


@dataclass(frozen=True)
class PeakRun:
    """What :func:`run_with_peak` measured of a command."""

    code: int  # exit code (negative: killed by that signal)
    seconds: float  # wall time
    peak_kib: int  # its own peak RSS
    tree_kib: int  # its own peak plus every process it started's (a sum of peaks: an upper bound of the total)


def run_with_peak(cmd: Sequence[str], out: Path, err: Path, deadline_s: float,
                  env: dict[str, str] | None = None) -> PeakRun:
    """Run ``cmd`` with stdout/stderr to the files ``out``/``err``, reading its own peak RSS and its descendants'
    every 20 ms while it lives; killed after ``deadline_s`` (stuck). The peak is the process's own high-water mark
    (``VmHWM``, monotonic): wait4's ``ru_maxrss`` starts from the parent's at the fork on Linux, so under pytest it
    measured the test process, not the command."""
    import subprocess

    with open(out, "w") as fo, open(err, "w") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(cmd), stdout=fo, stderr=fe, env=env)
    deadline = time.monotonic() + deadline_s
    peak = 0
    others: dict[int, int] = {}
    while True:
        peak = max(peak, _hwm_kib(proc.pid))  # (a zombie's status has no VmHWM: 0, the peak read before stands)
        for kid in _descendants(proc.pid):
            others[kid] = max(others.get(kid, 0), _hwm_kib(kid))
        pid, status, _ = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() > deadline:
            proc.kill()
            pid, status, _ = os.wait4(proc.pid, 0)
            break
        time.sleep(0.02)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return PeakRun(proc.returncode, time.perf_counter() - t0, peak, peak + sum(others.values()))
