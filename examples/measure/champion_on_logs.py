"""Champion/challenger on a bundled log played back to back (as ``streamid replay NAME --max-speed --loop N``).

Usage: ``python examples/measure/champion_on_logs.py mr_damper 4 [window_s=6000.0 update_every_s=1500.0 ...]``

Feeds the log N times, with time running on, to an ``OnlineIdentifier`` with default settings (or the
StreamConfig keywords given), identifies every window, and prints: windows decided, decisions by code,
drift events, and per output the free-run R2 of every published model on its held-out data and on the
whole log.  Used for the figures of issue 12 (no clock given: stream time runs faster than the clock,
so every window is identified, as in a max-speed replay).
"""

from __future__ import annotations

import ast
import sys
import time
from typing import Any

import numpy as np

from streamid import OnlineIdentifier, StreamConfig
from streamid.engine.validation import r2
from streamid.logs import bundled_log, read_log_arrays


def main(name: str, loops: int, overrides: dict) -> None:
    log = read_log_arrays(bundled_log(name))
    t, period = log.t_ns, int(np.median(np.diff(log.t_ns)))
    u, y = np.column_stack(list(log.inputs.values())), np.column_stack(list(log.outputs.values()))
    ins, outs = list(log.inputs), list(log.outputs)
    T = np.concatenate([t + k * t.size * period for k in range(loops)])
    U, Y = np.tile(u, (loops, 1)), np.tile(y, (loops, 1))
    ident = OnlineIdentifier(StreamConfig(**overrides), stream="s")
    ups, drifts, chunk, t0 = [], [], max(64, int(5e9 // period)), time.perf_counter()
    for a in range(0, T.size, chunk):
        ident.learn_many(T[a : a + chunk], U[a : a + chunk], Y[a : a + chunk], inputs=ins, outputs=outs)
        drifts += [int(e.t_ns or 0) for e in ident.drain_events() if e.kind == "drift"]
        ups += ident.update_all()
    st = ident.status()
    print(f"{name} x{loops} ({T.size * period / 1e9:.0f} s of stream): windows closed {st['windows']['closed']}, "
          f"coalesced {st['windows']['coalesced']}, decided {len(ups)}; decisions {st['decisions']}; "
          f"drift events {len(drifts)}; {time.perf_counter() - t0:.1f} s wall")
    for k, out in enumerate(outs):
        acc = [x for x in ups if x.accepted and x.output == out]
        if not acc:
            print(f"  {out}: nothing published")
            continue
        val = np.array([x.metrics["r2_fr_val"] for x in acc])
        whole = np.array([_whole(x.model, u, y[:, k]) for x in acc])
        print(f"  {out}: published {len(acc)}; FR R2 held out min {val.min():.4f} median {np.median(val):.4f}; "
              f"whole log min {whole.min():.4f} median {np.median(whole):.4f}")


def _whole(model: Any, u: np.ndarray, y: np.ndarray) -> float:
    """Free-run R2 of ``model`` over the whole log, started from its first ``max_lag`` outputs."""
    lag = model.max_lag
    return r2(y[lag:], model.simulate(u, y[:lag])[lag:])


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1,
         {k: ast.literal_eval(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])})
