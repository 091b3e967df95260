"""Champion/challenger on a CSV record of one input and one output (e.g. the DaISy ball and beam).

Usage: ``python examples/measure/tuning_online.py FILE.csv INPUT OUTPUT PERIOD_S [seeds]``

Windows of a third of the record, a decision every twelfth, default settings otherwise; per seed:
decisions by code and the free-run R2 of the published models on their held-out data.
"""

from __future__ import annotations

import csv
import sys

import numpy as np

from streamid import OnlineIdentifier, StreamConfig


def main(path: str, inp: str, out: str, period_s: float, seeds: int) -> None:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    u = np.array([float(r[inp]) for r in rows])
    y = np.array([float(r[out]) for r in rows])
    n, period = len(rows), int(round(period_s * 1e9))
    t = np.arange(n, dtype=np.int64) * period
    for seed in range(seeds):
        ident = OnlineIdentifier(StreamConfig(window_samples=n // 3, update_every_samples=n // 12, seed=seed), stream="s")
        ident.learn_many(t, u, y, inputs=[inp], outputs=[out], period_ns=period)
        ups = ident.update_all()
        fr = [x.metrics["r2_fr_val"] for x in ups if x.accepted]
        figs = f"FR R2 min {min(fr):.3f} median {np.median(fr):.3f}" if fr else "nothing published"
        print(f"seed {seed}: {len(ups)} decided, {len(fr)} published {ident.status()['decisions']}; {figs}")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0], a[1], a[2], float(a[3]), int(a[4]) if len(a) > 4 else 3)
