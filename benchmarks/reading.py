"""``streamid bench`` section ``reading``: data files read into float64 columns (issue 53, items 3 and 5).

Generated in a temporary directory: a CSV of three float columns (``time_s,u,y``, ~1 GB; ~100 MB with
``--quick``), the 5,000,000-row CSV of two one-digit columns (20 MB: the file that took 1.68 GB with the
hand-written reader) and a 10,000,000-row Parquet file.  Each is read by
:func:`streamid.logs.datafile.load_table` with its columns named, in a fresh process: read MB/s (file bytes
over wall time) and the peak RSS over the process's RSS just before the read (imports done), against the
float64 columns it returns.

``python -m benchmarks.reading FILE COL [COL ...]`` measures one file and prints the figures as JSON.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["write_signals_csv", "write_digits_csv", "write_parquet", "measure_read", "bench"]


def _signal_blocks(rows: int, seed: int) -> Iterator[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    for start in range(0, rows, 1_000_000):
        n = min(1_000_000, rows - start)
        u = rng.uniform(-1, 1, n)
        yield {"time_s": (start + np.arange(n)) * 1e-3, "u": u, "y": np.cumsum(u) * 1e-3}


def write_signals_csv(path: Path, rows: int, seed: int = 0) -> int:
    """``time_s,u,y`` (1 kHz clock, uniform input, a random walk), shortest round-trip floats; its bytes."""
    from streamid.logs.arrow_tables import write_float_columns

    path.write_bytes(b"time_s,u,y\n")
    write_float_columns(str(path), _signal_blocks(rows, seed), "csv")
    return path.stat().st_size


def write_digits_csv(path: Path, rows: int = 5_000_000, seed: int = 0) -> int:
    """``u,y`` of one-digit integers, 4 bytes a row (5,000,000 rows: 20 MB); its bytes."""
    rng = np.random.default_rng(seed)
    cells = np.empty((rows, 4), dtype=np.uint8)
    cells[:, 0::2] = 48 + rng.integers(0, 10, (rows, 2), dtype=np.uint8)
    cells[:, 1], cells[:, 3] = ord(","), ord("\n")
    path.write_bytes(b"u,y\n" + cells.tobytes())
    return path.stat().st_size


def write_parquet(path: Path, rows: int, seed: int = 0) -> int:
    """``time_s,u,y`` float64 as Parquet (row groups of 1,000,000); its bytes."""
    from streamid.logs.arrow_tables import write_float_columns

    write_float_columns(str(path), _signal_blocks(rows, seed), "parquet")
    return path.stat().st_size


def _status_mib(field: str) -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _measure_here(path: str, columns: list[str]) -> dict[str, Any]:
    import time

    import streamid.logs.arrow_tables  # noqa: F401 - imported before the baseline: the read's cost only
    from streamid.logs.datafile import load_table

    base = _status_mib("VmRSS")
    t0 = time.perf_counter()
    table = load_table(path, columns=columns)
    wall = time.perf_counter() - t0
    # VmHWM: this process's own peak. Not ru_maxrss: on Linux it starts from the parent's RSS at the fork
    # (kept across exec), so under pytest or `streamid bench` it read ~230 MiB for a 134 MiB peak.
    peak = _status_mib("VmHWM")
    numeric = sum(v.nbytes for v in table.columns.values()) / 2**20
    return {"wall_s": wall, "mb_per_s": Path(path).stat().st_size / 1e6 / wall, "rss_over_start_mib": peak - base,
            "numeric_mib": numeric, "ratio": (peak - base) / numeric, "rows": len(table),
            "columns": sorted(table.columns)}


def measure_read(path: Path, columns: list[str]) -> dict[str, Any]:
    """Read ``path``'s ``columns`` in a fresh process: wall time, MB/s, peak RSS over the start, numeric MiB."""
    out = subprocess.run([sys.executable, "-m", "benchmarks.reading", str(path), *columns], capture_output=True,
                         text=True, timeout=600, check=True)
    return dict(json.loads(out.stdout))


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench`` provider: yields ``benchmarks.kit.Measurement`` rows."""
    from benchmarks.kit import Measurement

    quick = bool(getattr(options, "quick", False))
    repeat = max(1, int(getattr(options, "repeat", 1)))
    with tempfile.TemporaryDirectory(prefix="streamid-bench-read-") as tmp:
        work = Path(tmp)
        files = [
            ("CSV time_s,u,y (3 float columns)", work / "signals.csv",
             lambda p: write_signals_csv(p, 1_800_000 if quick else 18_000_000), ["u", "y"]),
            ("CSV 5,000,000 rows u,y (one digit each)", work / "digits.csv", write_digits_csv, ["u", "y"]),
            ("Parquet time_s,u,y", work / "signals.parquet",
             lambda p: write_parquet(p, 1_000_000 if quick else 10_000_000), ["u", "y"]),
        ]
        for case, path, make, cols in files:
            size = make(path)
            runs = [measure_read(path, cols) for _ in range(repeat)]
            what = f"{case}, {size / 1e6:.0f} MB, {runs[0]['rows']:,} rows, read {', '.join(runs[0]['columns'])}"
            yield Measurement("reading", what, "read speed", "MB/s", tuple(r["mb_per_s"] for r in runs))
            yield Measurement("reading", what, "peak RSS over start", "MiB", tuple(r["rss_over_start_mib"] for r in runs),
                              note=f"float64 columns {runs[0]['numeric_mib']:.0f} MiB")
            yield Measurement("reading", what, "peak RSS / float64 columns", "x", tuple(r["ratio"] for r in runs))
            path.unlink()


if __name__ == "__main__":
    print(json.dumps(_measure_here(sys.argv[1], sys.argv[2:])))
