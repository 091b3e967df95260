"""Drift of a simulated device through an ``OnlineIdentifier``: time to the drift event and to a new champion.

Usage: ``python examples/measure/drift_sim.py DEVICE SECONDS DRIFT_AT_S CHANGE SEED [window_s]``
(``DRIFT_AT_S`` 0: no change, a stationary record: every drift event is a false alarm).

Samples go in 0.1 s batches and every due window is identified at once (an infinitely fast worker), so
the delays printed are in stream time.  The same runs are the drift rows of ``streamid bench --only online``
(:func:`benchmarks.online_cases.drift_run`).
"""

from __future__ import annotations

import sys

from benchmarks.online_cases import drift_run


def main(device: str, seconds: float, drift_at_s: float, change: float, seed: int, window_s: float) -> None:
    r = drift_run(device, seconds, drift_at_s, change, seed, window_s)
    print(f"{device} {seconds:g} s seed {seed}: decisions {r['decisions']}")
    if drift_at_s <= 0:
        print(f"  stationary: {r['false_alarms']} drift events (false alarms)")
        return
    print(f"  false alarms before the change: {r['false_alarms']}")
    print(f"  drift event: {r['detect_s']:.2f} s after the change" if r["detect_s"] == r["detect_s"]
          else "  no drift event after it")
    print(f"  new champion: window ending {r['new_champion_s']:.2f} s after the change (FR R2 "
          f"{r['new_champion_r2_fr_val']:.3f}{', recalibrated' if r['new_champion_recalibrated'] else ''})"
          if r["new_champion_s"] == r["new_champion_s"] else "  no new champion after it")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0], float(a[1]), float(a[2]), float(a[3]), int(a[4]), float(a[5]) if len(a) > 5 else 10.0)
