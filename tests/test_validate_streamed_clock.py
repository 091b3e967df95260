"""A clock whose steps jitter (more than ``MAX_STEPS`` distinct steps, as real lab logs' clocks do) in a record read
a piece at a time (issue 53 item 2): its median step found exactly (``logs.pieces.kth_steps``, passes over the time
column alone) so that ``streamid validate`` streams such a file, with the whole-file path's period and "read" line."""

from __future__ import annotations

import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_validate_streamed import _record, _run, _same_report, models  # noqa: E402,F401 - its fixture too

import streamid.logs.pieces as pieces  # noqa: E402
from streamid.model.narx import Model  # noqa: E402

N = 200_000


@pytest.mark.parametrize("buckets", [16, 1 << 16])
def test_kth_steps_are_the_sorted_values(buckets: int) -> None:
    """Any int64 values (a narrow jitter, wide outliers, the int64 range's ends) in random pieces: the k-th
    smallest exactly, in at most ceil(63 / log2(buckets)) + 1 passes."""
    rng = np.random.default_rng(4096)
    big = np.iinfo(np.int64).max
    for trial in range(30):
        n = int(rng.integers(1, 5000))
        d = 1_000_000 + rng.integers(-20_000, 20_000, n)
        if trial % 3 == 1:
            d[rng.integers(0, n, 5)] = rng.integers(1, 10**12, 5)  # pauses and a dropped sample or two
        if trial % 3 == 2:
            d = rng.integers(1, big, n, dtype=np.int64)
            d[0], d[-1] = 1, big
        cuts = np.unique(np.concatenate([[0], rng.integers(0, n, 20), [n]]))
        passes = [0]

        def steps() -> object:
            passes[0] += 1
            return (d[a:b] for a, b in zip(cuts[:-1], cuts[1:]))

        ks = sorted({0, n - 1, (n - 1) // 2, n // 2, int(rng.integers(0, n))})
        got = pieces.kth_steps(steps, int(d.min()), int(d.max()), ks, buckets)  # type: ignore[arg-type]
        assert got == [int(v) for v in np.sort(d)[ks]], trial
        assert passes[0] <= -(-63 // int(np.log2(buckets))) + 1, passes


@pytest.mark.parametrize("n", [5000, 5001])
def test_a_jittered_clocks_period_is_the_whole_columns_median(n: int) -> None:
    rng = np.random.default_rng(n)
    v = np.cumsum(0.001 + rng.uniform(-2e-5, 2e-5, n)) + 3.0
    t = np.round(v * 1e9).astype(np.int64)
    assert np.unique(np.diff(t)).size > pieces.MAX_STEPS
    clock = pieces._Clock(10**9)
    cuts = np.arange(0, n + 700, 700)
    for a, b in zip(cuts[:-1], cuts[1:]):
        clock.add(v[a:b])
    assert clock.steps is None  # too many to count as they pass
    assert clock.period(lambda: (v[a:b] for a, b in zip(cuts[:-1], cuts[1:]))) == int(np.median(np.diff(t)))


def _write(path: Path, u: np.ndarray, y: np.ndarray, t_s: np.ndarray) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {"time_s": t_s, "volt": u, "um": y}
    if path.suffix == ".csv":
        with open(path, "w") as fh:
            fh.write(",".join(cols) + "\n")
            np.savetxt(fh, np.column_stack(list(cols.values())), delimiter=",", fmt="%.17g")
    else:
        pq.write_table(pa.table(cols), path)


def _jittered(n: int, seed: int) -> np.ndarray:
    """A 1 kHz clock whose steps jitter by up to 20 us, and a 2 s pause: ~40,000 distinct steps (ns)."""
    rng = np.random.default_rng(seed)
    steps = 0.001 + rng.uniform(-2e-5, 2e-5, n)
    steps[n // 3] = 2.0
    return np.asarray(np.cumsum(steps) + 100.0)


@pytest.mark.parametrize("suffix,n", [(".parquet", N), (".csv", N + 1)])
def test_a_jittered_clock_streams_with_the_whole_files_period(tmp_path: Path, models: dict[str, tuple[Path, Model]],
                                                              suffix: str, n: int) -> None:
    path = models["ensemble"][0]
    u, y = _record(n)
    t = _jittered(n, seed=n)
    assert np.unique(np.diff(np.round(t * 1e9).astype(np.int64))).size > 9 * pieces.MAX_STEPS
    data = tmp_path / f"rec{suffix}"
    _write(data, u, y, t)
    got = _run([str(path), str(data)], streamed=True)
    whole = _run([str(path), str(data)], streamed=False)
    _same_report(got, whole)
    for k in ("notes", "caveats", "data", "model", "passed"):
        assert got[k] == whole[k], (k, got[k], whole[k])
    assert got["data"]["read"]["clock"] == "time_s"
    assert got["data"]["period_ns"] == int(np.median(np.diff(np.round(t * 1e9).astype(np.int64))))
    assert got["data"]["period_ns"] != 1_000_000  # the jitter's median, not the nominal step
    span = ["--start", "20", "--end", "150"]  # the rows the jittered clock picks (and the pause in them)
    assert _run([str(path), str(data), *span], streamed=True)["data"] == _run([str(path), str(data), *span],
                                                                              streamed=False)["data"]


def test_memory_with_a_jittered_clock_does_not_grow_with_the_record(tmp_path: Path,
                                                                    models: dict[str, tuple[Path, Model]]) -> None:
    """The passes over the time column hold their counts (2 x 65,536 of them) and a piece: 900,000 samples peak
    (tracemalloc) within 1 MB of 300,000."""
    path = models["single"][0]
    peaks = []
    for n in (300_000, 900_000):
        u, y = _record(n, seed=n)
        data = tmp_path / f"rec{n}.parquet"
        _write(data, u, y, _jittered(n, seed=n))
        _run([str(path), str(data)], streamed=True)  # compiled kernels and imports first
        tracemalloc.start()
        try:
            _run([str(path), str(data)], streamed=True)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] - peaks[0] < 1_000_000, peaks
