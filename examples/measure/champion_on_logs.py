"""Champion/challenger on a bundled log played back to back (as ``streamid replay NAME --max-speed --loop N``).

Usage: ``python examples/measure/champion_on_logs.py mr_damper 4 [window_s=6000.0 update_every_s=1500.0 ...]``

Feeds the log N times, with time running on, to an ``OnlineIdentifier`` with default settings (or the
StreamConfig keywords given), identifies every window, and prints: windows decided, decisions by code,
drift events, and per output the free-run R2 of every published model on its held-out data and on
the whole log.  The same run is the first row of ``streamid bench --only online``
(:func:`benchmarks.online_cases.every_window`).
"""

from __future__ import annotations

import ast
import sys

import numpy as np

from benchmarks.online_cases import every_window


def main(name: str, loops: int, overrides: dict) -> None:
    r = every_window(name, loops, **overrides)
    print(f"{name} x{loops} ({r['stream_s']:.0f} s of stream): windows closed {r['windows_closed']}, "
          f"coalesced {r['coalesced']}, decided {r['decided']}; decisions {r['decisions']}; "
          f"drift events {r['drift_events']}; {r['wall_s']:.1f} s wall")
    for out, o in r["outputs"].items():
        if not o["published"]:
            print(f"  {out}: nothing published")
            continue
        val, whole = np.array(o["r2_fr_val"]), np.array(o["r2_fr_whole"])
        print(f"  {out}: published {o['published']}; FR R2 held out min {val.min():.4f} median {np.median(val):.4f}; "
              f"whole log min {whole.min():.4f} median {np.median(whole):.4f}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1,
         {k: ast.literal_eval(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])})
