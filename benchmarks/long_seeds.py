"""The bounded path beyond one chunk against the one-chunk path, over seeds (issue 53 item 1).

    python -m benchmarks.long_seeds --est 100000 --val 20000 --seeds 10

A long two-experiment record of the simulated reactor (:mod:`benchmarks.long_records`: estimation on a uniformly
random input, validation on random steps from a fresh state) or, with ``--device mr_damper``, of the simulated MR
damper (band-limited velocity noise, validated on a log sine sweep). Each seed is identified twice with the defaults:

* ``bounded``: as ``identify`` does on a record beyond one chunk (``CHUNK_ROWS`` rows): the search and the screen on
  the stratified sample, the candidates' free runs and the refinement on segments, the direct-term test and the
  pruned fits on evenly spaced rows;
* ``every row``: the same record with the chunk threshold raised above its length, i.e. the path every record of
  one chunk or less takes (the search on ``search_rows`` random rows, every candidate fitted and free-run on every
  row, the refinement over every row).
* ``search on every row`` (``--arms all-rows``, with ``bounded``): the one-chunk path with ``search_rows = 0``: the
  search itself evaluates every row of the record (about 15 times the bounded search's work at 100,000 samples).

Printed: each seed's validation free-run R^2 and wall time for both, then the median and the worst of each. CPU
heavy: run it under the bench lock.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator

import numpy as np

from benchmarks.long_records import reactor_record
from streamid.engine import identify
from streamid.engine.settings import DEFAULT
from streamid.engine.validation import r2_or_none

#: The modules whose ``CHUNK_ROWS`` decides the bounded path (raised together for the "every row" arm).
_THRESHOLDS = ("streamid.engine.search.rows", "streamid.engine.choice.scores", "streamid.engine.choice.selection",
               "streamid.model.ensemble")


@contextlib.contextmanager
def one_chunk_path(n: int) -> Iterator[None]:
    """Within: every record of up to ``n`` rows takes the one-chunk path (the threshold raised, then restored)."""
    import importlib

    mods = [importlib.import_module(m) for m in _THRESHOLDS]
    old = [getattr(m, "CHUNK_ROWS") for m in mods]
    try:
        for m in mods:
            setattr(m, "CHUNK_ROWS", n + 1)
        yield
    finally:
        for m, v in zip(mods, old):
            setattr(m, "CHUNK_ROWS", v)


def records(device: str, n_est: int, n_val: int) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The estimation and validation records: the reactor's uniform -> steps (:mod:`benchmarks.long_records`), or
    the simulated MR damper's band-limited noise -> log sine sweep (the suite's first damper pair, longer)."""
    if device == "reactor":
        return reactor_record(n_est, "uniform", 41), reactor_record(n_val, "steps", 42)
    from benchmarks.experiments import _band_noise, _mr, _sweep, _taper

    g = np.random.default_rng(202)
    return _mr(_taper(_band_noise(n_est, 200.0, (0.5, 10.0), 6.0, g)), 21), _mr(_taper(_sweep(n_val, 200.0, 0.5, 8.0, 12.0)), 22)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--est", type=int, default=100_000)
    ap.add_argument("--val", type=int, default=20_000)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--device", choices=("reactor", "mr_damper"), default="reactor")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--bounded-rows", type=int, default=0,
                    help="the bounded arm's search rows (search_rows; 0: the default's), e.g. 6528 for the online bound")
    ap.add_argument("--arms", choices=("both", "bounded", "all-rows"), default="both")
    a = ap.parse_args(argv)
    (u, y), (uv, yv) = records(a.device, a.est, a.val)
    arms = {"both": ("bounded", "every row"), "bounded": ("bounded",), "all-rows": ("bounded", "search on every row")}
    res: dict[str, list[tuple[float, float]]] = {arm: [] for arm in arms[a.arms]}
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        for arm in res:
            cfg = DEFAULT.replace(search_rows=a.bounded_rows) if (arm == "bounded" and a.bounded_rows) else DEFAULT
            if arm == "search on every row":
                cfg = DEFAULT.replace(search_rows=0)
            with one_chunk_path(a.est) if arm != "bounded" else contextlib.nullcontext():
                t0 = time.perf_counter()
                m = identify(u[:, None], y, cfg, seed).model
                s = time.perf_counter() - t0
            L = m.max_lag
            with np.errstate(over="ignore", invalid="ignore"):
                r = r2_or_none(yv[L:], m.simulate(uv[:, None], yv[:L])[L:])
            res[arm].append((-np.inf if r is None else float(r), s))
            print(f"seed {seed} {arm}: r2 fr val {r}, {s:.1f} s", flush=True)
    for arm, rows in res.items():
        r2s, secs = np.array([r for r, _ in rows]), np.array([s for _, s in rows])
        print(f"{arm}: {len(rows)} seeds, r2 fr val median {np.median(r2s):.6f} worst {r2s.min():.6f}; "
              f"time median {np.median(secs):.1f} s", flush=True)


if __name__ == "__main__":
    main()
