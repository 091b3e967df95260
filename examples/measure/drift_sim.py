"""Drift of a simulated device through an ``OnlineIdentifier``: time to the drift event and to a new champion.

Usage: ``python examples/measure/drift_sim.py DEVICE SECONDS DRIFT_AT_S CHANGE SEED [window_s]``
(``DRIFT_AT_S`` 0: no change, a stationary record: every drift event is a false alarm).

Samples go in 0.1 s batches and every due window is identified at once (an infinitely fast worker), so
the delays printed are in stream time.  Used for the figures of issue 12.
"""

from __future__ import annotations

import sys

from streamid import OnlineIdentifier, StreamConfig
from streamid.sim import get_device
from streamid.sim.drift import drift_start_ns, simulate_drift


def main(device: str, seconds: float, drift_at_s: float, change: float, seed: int, window_s: float) -> None:
    if drift_at_s > 0:
        t, u, y = simulate_drift(device, seconds, drift_at_s, change, seed)
        change_ns: int | None = drift_start_ns(device, drift_at_s)
    else:
        t, u, y = get_device(device).simulate_seconds(seconds, seed=seed)
        change_ns = None
    ident = OnlineIdentifier(StreamConfig(window_s=window_s, update_every_s=1.0), stream="d")
    step = max(1, int(round(0.1e9 / (t[1] - t[0]))))
    drifts, champions = [], []
    for k in range(0, t.size, step):
        ident.learn_many(t[k : k + step], u[k : k + step], y[k : k + step], inputs=["u"], outputs=["y"])
        drifts += [int(e.t_ns or 0) for e in ident.drain_events() if e.kind == "drift"]
        champions += [(up.window.t_end_ns, up.metrics["r2_fr_val"]) for up in ident.update_all() if up.accepted]
    print(f"{device} {seconds:g} s seed {seed}: decisions {ident.status()['decisions']}")
    if change_ns is None:
        print(f"  stationary: {len(drifts)} drift events (false alarms)")
        return
    before = [d for d in drifts if d < change_ns]
    after = [d for d in drifts if d >= change_ns]
    new = [c for c in champions if c[0] > change_ns]
    print(f"  false alarms before the change: {len(before)}")
    print(f"  drift event: {(after[0] - change_ns) / 1e9:.2f} s after the change" if after else "  no drift event after it")
    print(f"  new champion: window ending {(new[0][0] - change_ns) / 1e9:.2f} s after the change (FR R2 {new[0][1]:.3f})"
          if new else "  no new champion after it")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0], float(a[1]), float(a[2]), float(a[3]), int(a[4]), float(a[5]) if len(a) > 5 else 10.0)
