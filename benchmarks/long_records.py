"""``streamid bench --only long``: identification and validation of long generated records (issue 53).

The simulated polymerization reactor (:mod:`streamid.sim.reactor`, the paper's; its simulation is the fastest of the
registered devices: ~1 s per 1,000,000 samples here) driven as the suite's "uniform->steps" pair
(:mod:`benchmarks.experiments`): estimation on a uniformly random input, validation on random steps. Each figure
is a child process running the command a user runs (``streamid identify`` / ``streamid validate`` with the
defaults, ``--progress never``) on a Parquet file written beforehand; its wall time and its own peak RSS
(``VmHWM`` of /proc/<pid>/status polled every 20 ms: on Linux ``ru_maxrss`` of a child starts from the parent's), and
for ``identify`` the sum of the peaks of it and of the worker processes it starts for its restarts.

Cases (targets of issue 53 in brackets): 1,000,000 estimation samples (+ 100,000 validation) [<= 10 s, <= 400 MB];
10,000,000 samples (9,000,000 estimation + 1,000,000 validation) [<= 60 s, <= 1 GB]; validation of a 10,000,000-
sample record by a saved model [<= 15 s]. ``--quick``: a tenth of each.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.kit import Measurement, run_with_peak

SECTION = "long"
#: A child that runs longer than this is stopped (a bound on a stuck run, not a measure of speed).
DEADLINE_S = 1800.0


def reactor_record(n: int, kind: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` samples of the simulated reactor under the suite's excitation ``kind`` ("uniform" or "steps")."""
    from benchmarks.experiments import _reactor, _steps
    from streamid.sim.reactor import ReactorParams

    p = ReactorParams()
    g = np.random.default_rng(seed)
    u = g.uniform(p.u_low, p.u_high, n) if kind == "uniform" else _steps(n, (10, 40), p.u_low, p.u_high, g)
    return _reactor(u, seed)


def write_record(path: Path, parts: list[tuple[np.ndarray, np.ndarray]]) -> int:
    """The parts one after another in a Parquet file of columns ``u`` and ``y``; its rows."""
    from streamid.logs.arrow_tables import write_float_columns

    write_float_columns(str(path), ({"u": np.asarray(u, dtype=np.float64), "y": np.asarray(y, dtype=np.float64)}
                                    for u, y in parts), "parquet")
    return sum(len(y) for _, y in parts)


def run_measured(args: list[str], workdir: Path) -> dict[str, Any]:
    """``python -m streamid ARGS`` in a child: its exit code, wall seconds, own peak RSS (MiB), stdout, and
    ``tree_mib``: the sum of the peaks of it and every process it started (``identify`` runs its restarts in worker
    processes; a sum of peaks bounds the simultaneous total from above)."""
    cmd = [sys.executable, "-m", "streamid", *args]
    run = run_with_peak(cmd, workdir / "out", workdir / "err", DEADLINE_S, {**os.environ, "PYTHONUNBUFFERED": "1"})
    if run.code != 0:
        raise RuntimeError(f"{' '.join(args)} exited {run.code}: {(workdir / 'err').read_text()[-2000:]}")
    return {"code": run.code, "seconds": run.seconds, "peak_mib": run.peak_kib / 1024.0, "tree_mib": run.tree_kib / 1024.0,
            "stdout": (workdir / "out").read_text()}


def cases(quick: bool) -> list[tuple[str, int, int]]:
    """(case name, estimation samples, validation samples) of the identify cases."""
    k = 10 if quick else 1
    return [(f"identify {1_000_000 // k:,} est + {100_000 // k:,} val (Parquet)", 1_000_000 // k, 100_000 // k),
            (f"identify {9_000_000 // k:,} est + {1_000_000 // k:,} val (Parquet)", 9_000_000 // k, 1_000_000 // k)]


def bench(options: Any) -> Iterator[Measurement]:
    repeat = 1 if options.quick else max(1, min(3, int(options.repeat)))
    with tempfile.TemporaryDirectory(prefix="streamid-long-") as tmp:
        work = Path(tmp)
        model = work / "model.json"
        for name, n_est, n_val in cases(options.quick):
            data = work / f"rec_{n_est}.parquet"
            write_record(data, [reactor_record(n_est, "uniform", 41), reactor_record(n_val, "steps", 42)])
            runs = [run_measured(["identify", str(data), "--input", "u", "--output", "y", "--est", str(n_est),
                                  "--progress", "never", "--json", "--model", str(model), "--seed", str(options.seed + i)],
                                 work) for i in range(repeat)]
            doc = json.loads(runs[-1]["stdout"])
            note = f"r2 fr val {_r2_fr_val(doc)}; search rows {_search_rows(model)}"
            yield Measurement(SECTION, name, "identify time", "s", tuple(r["seconds"] for r in runs), note)
            yield Measurement(SECTION, name, "peak RSS", "MiB", tuple(r["peak_mib"] for r in runs))
            yield Measurement(SECTION, name, "peak RSS with its workers", "MiB", tuple(r["tree_mib"] for r in runs))
            data.unlink()
        n_val = 10_000_000 // (10 if options.quick else 1)
        data = work / "val.parquet"
        write_record(data, [reactor_record(n_val, "steps", 43)])
        runs = [run_measured(["validate", str(model), str(data), "--input", "u", "--output", "y", "--json"], work)
                for _ in range(repeat)]
        name = f"validate {n_val:,} samples (Parquet)"
        yield Measurement(SECTION, name, "validate time", "s", tuple(r["seconds"] for r in runs))
        yield Measurement(SECTION, name, "peak RSS", "MiB", tuple(r["peak_mib"] for r in runs))


def _r2_fr_val(doc: Any) -> str:
    try:  # identify's JSON report: the summary over its runs (one identification: one value)
        return f"{float(doc['summary']['r2']['fr_val']['median']):.6f}"
    except (KeyError, TypeError, ValueError):
        return "?"


def _search_rows(model: Path) -> str:
    try:
        ev = json.loads(model.read_text())["metrics"].get("search_rows")
        return "all" if ev is None else f"{ev['rows']:,} of {ev['of']:,}"
    except (OSError, KeyError, TypeError, ValueError):
        return "?"
