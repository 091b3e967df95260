"""A small diagnostics writer for the .rrd tests, run as a subprocess (and killed with SIGKILL).

``python tests/rrd_writer.py PATH ROTATE_S [UPDATES_PER_S]`` draws one update of stream ``s`` every
1/UPDATES_PER_S seconds of wall time through :class:`streamid.viz.rerun_view.Viz` (the daemon's
writer) into PATH, rotating every ROTATE_S seconds, and prints ``drawn v<N>`` after each update
(flushed), ``rotated <files>`` whenever a segment was closed.  It never stops by itself before
120 s: the test ends it.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from streamid.engine.validation import CorrelationTest
from streamid.viz.rerun_view import UpdateReport, Viz, VizSettings

P = 5_000_000  # sample period [ns]


def report(version: int, n_val: int = 200) -> UpdateReport:
    """Update ``version`` of stream ``s``: its window ends at ``version`` seconds of stream time."""
    rng = np.random.default_rng(version)
    end = 10**9 * version
    t0 = end - (n_val - 1) * P
    u = np.sin(np.arange(n_val) * 0.2)
    y = np.tanh(u) + 0.01 * rng.normal(size=n_val)
    lags = tuple(range(11))
    corr = tuple(CorrelationTest(k, k, lags, tuple(np.r_[1.0, 0.05 * rng.normal(size=10)].tolist()), 0.14)
                 for k in ("ee", "ue", "e_eu", "u2_e", "u2_e2"))
    gens = 10 if version == 1 else 5
    return UpdateReport(
        stream="s", version=version, accepted=True, warm=version > 1, generations=gens, window_t0_ns=t0 - 100 * P,
        window_end_ns=end, period_ns=P, val_t0_ns=t0, y_val=y, osa_val=y + 0.01, fr_val=y * 0.98, u_val=u,
        input_name="v", output_name="f", fitness=np.geomspace(2.0, 1.0, gens), correlations=corr,
        lags={"y": [1], "u": [[1, 2]]}, metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.9}, identification_s=0.1,
        latency_s=0.12,
    )


def main(path: str, rotate_s: float, rate_hz: float = 10.0) -> None:
    viz = Viz(VizSettings(rrd=path, rrd_rotate_s=rotate_s, recording_id="rrd-writer"))
    viz.add_stream("s")
    rotations = 0
    end = time.monotonic() + 120.0
    v = 0
    while time.monotonic() < end:
        v += 1
        viz.log_update(report(v))
        print(f"drawn v{v}", flush=True)
        stats = viz.file_stats
        if stats["rotations"] != rotations:
            rotations = stats["rotations"]
            print("rotated " + " ".join(viz.files), flush=True)
        time.sleep(1.0 / rate_hz)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), *(float(a) for a in sys.argv[3:4]))
