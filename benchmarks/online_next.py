"""The online path on the next experiment: the champion an OnlineIdentifier serves after experiment A, judged on B.

``python -m benchmarks.online_next OUT.json [PAIR ...]``: for each simulated device's two-experiment pairs
(:mod:`benchmarks.experiments`, PAIR the pair indices, default 0) and seeds 0-4, experiment A's estimation record is
fed to an :class:`~streamid.OnlineIdentifier` (windows of a quarter of the record, an update every twentieth; the
default refresh policy, and every update a coevolution run), and the served champion's free-run R^2 on experiment B is
printed, one JSON line a case. Run it on two checkouts (``PYTHONPATH``) to compare an online change; docs/benchmarks.md
has the figures (issue 51: a median of the recent runs as the challenger, tried and not taken).
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import numpy as np

from benchmarks.experiments import pair
from streamid import OnlineIdentifier, StreamConfig
from streamid.online import RefreshPolicy

__all__ = ["case", "main"]

RATES_HZ = {"piezo": 2000, "mr_damper": 200, "bouc_wen": 750}


def case(system: str, seed: int, k: int = 0, runs_only: bool = False) -> dict[str, Any]:
    """One record A -> B: the served champion's free-run R^2 on B and how it was made."""
    e = pair(system + "_sim")[k]
    n = e.y_est.size
    t = (np.arange(n) * (1e9 / RATES_HZ[system])).astype(np.int64)
    cfg = StreamConfig(window_samples=n // 4, update_every_samples=n // 20, seed=seed, max_pending_windows=64)
    ident = OnlineIdentifier(cfg, stream="b", refresh=RefreshPolicy(enabled=False) if runs_only else None)
    ident.learn_many(t, e.u_est, e.y_est, inputs=["u"], outputs=["y"])
    t0 = time.perf_counter()
    ups = ident.update_all()
    m = ident.models["y"]  # the served champion
    L = m.max_lag
    with np.errstate(all="ignore"):
        fr = m.simulate(e.u_val, e.y_val[:L])
    ok = bool(np.all(np.isfinite(fr)))
    r2 = 1 - float(np.mean((e.y_val[L:] - fr[L:]) ** 2)) / float(np.var(e.y_val[L:])) if ok else float("-inf")
    return {"runs_only": runs_only, "system": system, "pair": e.label, "seed": seed, "r2_fr_B": r2,
            "champion": type(m).__name__, "members": len(getattr(m, "members", ())) or 1, "updates": len(ups),
            "accepted": sum(u.accepted for u in ups), "seconds": round(time.perf_counter() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out, pairs = args[0], [int(a) for a in args[1:]] or [0]
    rows = []
    for k in pairs:
        for system in RATES_HZ:
            for seed in range(5):
                for runs_only in (False, True):
                    rows.append(case(system, seed, k, runs_only))
                    print(json.dumps(rows[-1]), flush=True)
    with open(out, "w", encoding="utf-8") as f:
        json.dump(rows, f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
