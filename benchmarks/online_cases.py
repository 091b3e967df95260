"""The online section of ``streamid bench``: the figures of issue 12, measured through the online core.

Every case feeds records to an :class:`~streamid.online.OnlineIdentifier` with default settings, in
batches, and identifies every window that is due at once (no clock given: stream time runs faster
than the clock, as in ``streamid replay --max-speed``), so delays are in stream time:

* **every window of a log**: the bundled MR damper log played ``loops`` times back to back; every
  update window identified, and per published model its free-run R^2 on its held-out data and on
  the whole log (:func:`every_window`; ``examples/measure/champion_on_logs.py`` prints it);
* **drift**: a simulated device whose output-level parameters change by ``change`` at a known time
  (:mod:`streamid.sim.drift`); time from the change to the ``drift`` event and to the first champion
  accepted on a window ending after it, and false alarms before it (:func:`drift_run`;
  ``examples/measure/drift_sim.py``);
* **false alarms**: the same on stationary records (the simulated damper, the looped real logs: the MR damper,
  the piezo, and each of the F-16's two experiments alone).

The piezo's decision latency in real time is in the daemon section (a real daemon over Zenoh).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from benchmarks.kit import Measurement

SECTION = "online"

__all__ = ["SECTION", "bench", "drift_run", "every_window", "looped_log"]


def looped_log(name: str, loops: int, part: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          list[str], list[str]]:
    """A bundled log played ``loops`` times back to back, time running on: ``(t_ns, u, y, inputs, outputs)``.

    ``part`` 0 or 1 plays only the log's first or second part, split at its metadata's ``estimation_samples``
    (the F-16's two experiments, one steady-state period of the multisine each: level 3, then level 2).
    """
    from streamid.logs import bundled_log, read_log_arrays

    log = read_log_arrays(bundled_log(name))
    t, period = log.t_ns - log.t_ns[0], int(np.median(np.diff(log.t_ns)))
    u, y = np.column_stack(list(log.inputs.values())), np.column_stack(list(log.outputs.values()))
    if part is not None:
        if part not in (0, 1):
            raise ValueError(f"looped_log part must be 0 (before estimation_samples), 1 (from it) or None; got {part!r}")
        split = int(str(log.metadata["streamid"]["estimation_samples"]).split()[0])
        rows = slice(0, split) if part == 0 else slice(split, t.size)
        t, u, y = t[rows] - t[rows][0], u[rows], y[rows]
    T = np.concatenate([t + k * t.size * period for k in range(loops)])
    return T, np.tile(u, (loops, 1)), np.tile(y, (loops, 1)), list(log.inputs), list(log.outputs)


def every_window(name: str = "mr_damper", loops: int = 4, **overrides: Any) -> dict[str, Any]:
    """Champion/challenger on a bundled log played ``loops`` times (as ``replay NAME --max-speed --loop N``)."""
    from streamid import OnlineIdentifier, StreamConfig
    from streamid.engine.validation import r2
    from streamid.logs import bundled_log, read_log_arrays

    T, U, Y, ins, outs = looped_log(name, loops)
    period = int(T[1] - T[0])
    ident = OnlineIdentifier(StreamConfig(**overrides), stream="s")
    ups: list[Any] = []
    drifts = 0
    chunk, t0 = max(64, int(5e9 // period)), time.perf_counter()
    for a in range(0, T.size, chunk):
        ident.learn_many(T[a : a + chunk], U[a : a + chunk], Y[a : a + chunk], inputs=ins, outputs=outs)
        drifts += sum(1 for e in ident.drain_events() if e.kind == "drift")
        ups += ident.update_all()
    st = ident.status()
    log = read_log_arrays(bundled_log(name))
    u1, y1 = np.column_stack(list(log.inputs.values())), np.column_stack(list(log.outputs.values()))
    per_output = {}
    for k, out in enumerate(outs):
        acc = [x for x in ups if x.accepted and x.output == out]
        whole = [r2(y1[x.model.max_lag :, k], x.model.simulate(u1, y1[: x.model.max_lag, k])[x.model.max_lag :])
                 for x in acc]
        per_output[out] = {"published": len(acc), "r2_fr_val": [float(x.metrics["r2_fr_val"]) for x in acc],
                           "r2_fr_whole": [float(v) for v in whole]}
    return {"stream_s": T.size * period / 1e9, "windows_closed": st["windows"]["closed"],
            "coalesced": st["windows"]["coalesced"], "decided": len(ups), "decisions": dict(st["decisions"]),
            "drift_events": drifts, "outputs": per_output, "wall_s": time.perf_counter() - t0}


def drift_run(device: str, seconds: float, drift_at_s: float, change: float, seed: int,
              window_s: float = 10.0, record: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              **overrides: Any) -> dict[str, Any]:
    """Drift events and champions of ``device`` simulated with a change (``drift_at_s`` 0: stationary).

    Samples go in 0.1 s batches and every due window is identified at once (update every 1 s).
    ``record`` replaces the simulation by a given ``(t_ns, u, y)`` (stationary); ``overrides`` are
    :class:`~streamid.StreamConfig` fields.
    """
    from streamid import OnlineIdentifier, StreamConfig
    from streamid.sim import get_device
    from streamid.sim.drift import drift_start_ns, simulate_drift

    change_ns: int | None = None
    if record is not None:
        t, u, y = record
    elif drift_at_s > 0:
        t, u, y = simulate_drift(device, seconds, drift_at_s, change, seed)
        change_ns = drift_start_ns(device, drift_at_s)
    else:
        t, u, y = get_device(device).simulate_seconds(seconds, seed=seed)
    u2 = u.reshape(t.size, -1)
    y2 = y.reshape(t.size, -1)
    ident = OnlineIdentifier(StreamConfig(**{"window_s": window_s, "update_every_s": 1.0, **overrides}), stream="d")
    step = max(1, int(round(0.1e9 / (t[1] - t[0]))))
    drifts: list[int] = []
    champions: list[tuple[int, float, bool]] = []  # (window end, FR R2 held out, recalibrated)
    ins, outs = [f"u{i}" for i in range(u2.shape[1])], [f"y{i}" for i in range(y2.shape[1])]
    for k in range(0, t.size, step):
        ident.learn_many(t[k : k + step], u2[k : k + step], y2[k : k + step], inputs=ins, outputs=outs)
        drifts += [int(e.t_ns or 0) for e in ident.drain_events() if e.kind == "drift"]
        champions += [(up.window.t_end_ns, float(up.metrics["r2_fr_val"]),
                       "recalibrated_gain" in (up.model.metrics if up.model is not None else {}))
                      for up in ident.update_all() if up.accepted]
    out: dict[str, Any] = {"device": device, "seed": seed, "change": change, "seconds": seconds,
                           "decisions": dict(ident.status()["decisions"]), "drift_events": len(drifts)}
    if change_ns is None:
        out["false_alarms"] = len(drifts)
        return out
    after = [d for d in drifts if d >= change_ns]
    new = [c for c in champions if c[0] > change_ns]
    out.update(false_alarms=len(drifts) - len(after),
               detect_s=(after[0] - change_ns) / 1e9 if after else float("nan"),
               new_champion_s=(new[0][0] - change_ns) / 1e9 if new else float("nan"),
               new_champion_r2_fr_val=new[0][1] if new else float("nan"),
               new_champion_recalibrated=bool(new and new[0][2]))
    return out


def _sweep(runs: list[dict[str, Any]]) -> Iterator[Measurement]:
    case = f"drift: MR damper sim, +-20 % at 30 s (alternating), {len(runs)} seeds"
    d = np.array([r["detect_s"] for r in runs])
    c = np.array([r["new_champion_s"] for r in runs])
    late = ", ".join(f"seed {r['seed']}: {r['detect_s']:.2f} s" for r in runs if not r["detect_s"] <= 3.0) or "none"
    slow = ", ".join(f"seed {r['seed']}: {r['new_champion_s']:.2f} s" for r in runs if not r["new_champion_s"] <= 5.0)
    yield Measurement(SECTION, case, "change -> drift event", "s", tuple(d),
                      f"within 3 s: {int(np.sum(d <= 3.0))} of {d.size}; later or never: {late}")
    yield Measurement(SECTION, case, "change -> new champion", "s", tuple(c),
                      f"within 5 s: {int(np.sum(c <= 5.0))} of {c.size}; later or never: {slow or 'none'}")
    yield Measurement(SECTION, case, "false alarms before the change", "count",
                      tuple(float(r["false_alarms"]) for r in runs))


#: (device, drift at s, change) of the drift cases; seeds are ``options.seed + i``
_DAMPER = [(30.0, 0.2), (30.0, -0.2), (30.0, 0.2), (30.0, -0.2), (30.0, 0.2), (30.0, -0.2), (25.0, 0.2), (35.0, -0.2)]


def bench(options: Any) -> Iterator[Measurement]:
    """The online section of ``streamid bench`` (see the module docstring)."""
    quick = bool(options.quick)
    ew = every_window("mr_damper", 1 if quick else 4)
    for out, o in ew["outputs"].items():
        case = f"MR damper log x{1 if quick else 4}, max speed, defaults"
        yield Measurement(SECTION, case, "windows identified", "count", (float(ew["decided"]),),
                          f"of {ew['windows_closed']} closed, {ew['coalesced']} coalesced; {ew['decisions']}")
        yield Measurement(SECTION, case, f"published {out}: FR R2 held out", "", tuple(o["r2_fr_val"]) or (np.nan,),
                          f"{o['published']} published")
        yield Measurement(SECTION, case, f"published {out}: FR R2 whole log", "", tuple(o["r2_fr_whole"]) or (np.nan,))
    damper = _DAMPER[:2] if quick else _DAMPER
    runs = [drift_run("mr_damper", 40.0 if quick else 60.0, at if not quick else 20.0, ch, options.seed + i)
            for i, (at, ch) in enumerate(damper)]
    runs_p = [drift_run("piezo", 4.0 if quick else 10.0, 2.0 if quick else 5.0, ch, options.seed + i, 0.5)
              for i, ch in enumerate((0.2, -0.2) if quick else (0.2, -0.2, 0.2))]
    for name, rs in (("MR damper sim", runs), ("piezo sim", runs_p)):
        case = f"drift: {name}, +-20 % gain at a known time, {len(rs)} seeds"
        seeds = ", ".join(f"{r['change']:+g}/seed {r['seed']}: {r['detect_s']:.2f} s" for r in rs)
        yield Measurement(SECTION, case, "change -> drift event", "s", tuple(r["detect_s"] for r in rs),
                          f"stream time; nan = not detected ({seeds})")
        yield Measurement(SECTION, case, "change -> new champion", "s", tuple(r["new_champion_s"] for r in rs),
                          f"window end; recalibrated: {sum(r['new_champion_recalibrated'] for r in rs)}")
        yield Measurement(SECTION, case, "false alarms before the change", "count",
                          tuple(float(r["false_alarms"]) for r in rs))
    # the same question over many seeds: the eight cases above are a sample, this is the distribution
    sweep = [drift_run("mr_damper", 45.0, 30.0, 0.2 if i % 2 == 0 else -0.2, options.seed + i)
             for i in range(4 if quick else 32)]
    yield from _sweep(sweep)
    secs = 60.0 if quick else 600.0
    st = [drift_run("mr_damper", secs, 0.0, 0.0, options.seed + i) for i in range(1 if quick else 2)]
    yield Measurement(SECTION, f"stationary MR damper sim, {secs:g} s", "false alarms", "count",
                      tuple(float(r["false_alarms"]) for r in st), f"{len(st)} seeds")
    for name, loops in (("mr_damper", 35), ("piezo_p885", 15)):
        n = 2 if quick else loops
        t, u, y, _, _ = looped_log(name, n)
        r = drift_run(name, 0.0, 0.0, 0.0, options.seed, record=(t, u, y))
        yield Measurement(SECTION, f"stationary: {name} log looped x{n} ({t[-1] / 1e9:.0f} s)", "false alarms", "count",
                          (float(r["false_alarms"]),), "window 10 s, update every 1 s")
    # the F-16 log is two experiments at two excitation levels: looped whole, its regime switches every 20.48 s
    # (docs/benchmarks.md); each experiment looped alone is a stationary record of a real structure
    for part, level in ((0, 3), (1, 2)):
        n = 2 if quick else 30
        t, u, y, _, _ = looped_log("f16_gvt", n, part)
        r = drift_run("f16_gvt", 0.0, 0.0, 0.0, options.seed, record=(t, u, y))
        yield Measurement(SECTION, f"stationary: f16_gvt level {level} alone looped x{n} ({t[-1] / 1e9:.0f} s, 3 outputs)",
                          "false alarms", "count", (float(r["false_alarms"]),), "window 10 s, update every 1 s")
