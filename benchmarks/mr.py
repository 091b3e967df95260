"""The real MR damper log at max speed: online models vs offline ``identify`` on the very same windows.

The bundled MR damper log (3499 samples at 200 Hz, 17.5 s) is put on Zenoh
back to back (it arrives in milliseconds).  The daemon's stream has
``max_pending_windows`` above the number of windows, so every window
(4 s every 0.5 s: 27 windows) is identified, in order: the first cold
(G = 400), the others warm-started (G = 30) from the previous one.

For each window, offline :func:`streamid.engine.identification.identify` (what
``streamid identify`` runs) is run cold with the same engine settings on the
same estimation samples, with ``seeds`` seeds, and validated on the same
validation part.  The offline free-run validation R^2 of a window varies with
the seed; its median over the seeds is the window's *offline reference*.

**Matches** means online is statistically one more offline run, judged on
the location and on the ranks:

1. no systematic deficit: the median over windows of
   ``online - offline median`` is >= ``-MATCH_TOL`` (0.01 R^2);
2. not ranked low: the online R^2 of a window has a percentile rank among
   that window's offline seeds (0 = below all, 1 = above all, ties half); if
   online were one more offline draw, the mean rank over windows would be
   0.5, with a standard error of about 0.06 for 27 windows and 6 seeds.
   It must be >= ``MATCH_MIN_RANK`` (0.4).

(Not "every window above the lowest offline seed": a run drawn from the very
same distribution falls below the lowest of 6 seeds in 1 window of 7.)  The
count of windows below the lowest seed is reported with that expectation.

The published model is the run's best pair by default; the case
``engine.selection = "fr_est"`` (best free run on the estimation part among
the best pair and the final population, as ``identify`` chooses with it) is
measured the same way, offline with the same setting.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from streamid.daemon.config import DaemonConfig
from streamid.online import StreamConfig
from streamid.daemon.service import Daemon
from streamid.transport import ZenohSettings

__all__ = ["mr_damper_max_speed", "MATCH_TOL", "MATCH_MIN_RANK", "MR_CONFIG"]

#: Tolerance of the "matches" definition (R^2 units), see the module docstring.
MATCH_TOL = 0.01
#: Lowest mean percentile rank of online among the offline seeds that still "matches".
MATCH_MIN_RANK = 0.4
#: The stream's settings: 4 s windows every 0.5 s, lags up to 4, 8 neurons, cold G=400, warm G=30.
MR_CONFIG = StreamConfig(window_s=4.0, update_every_s=0.5, max_lag_y=4, max_lag_u=4, neurons=8,
                         max_pending_windows=64)


def _free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def online_models(scfg: StreamConfig, timeout_s: float = 120.0) -> tuple[list[Any], dict[str, Any]]:
    """Replay the log at max speed into a daemon; returns the model updates received and the final status."""
    from replay.player import ReplayConfig, replay_log

    from streamid.transport.client import ModelSubscriber, latest_status
    from streamid.logs import bundled_log
    from streamid.transport import Bus

    ep = _free_endpoint()
    daemon = Daemon(DaemonConfig(streams=("mr_damper",), defaults=scfg), ZenohSettings(listen=(ep,))).start()
    got: list[Any] = []
    status: dict[str, Any] = {}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, ModelSubscriber(bus, "mr_damper", got.append, fetch_latest=False):
            replay_log(bundled_log("mr_damper.mcap"), bus=bus, config=ReplayConfig(max_speed=True))
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                status = latest_status(bus, "mr_damper", timeout_s=1.0) or {}
                ids = status.get("identifications", {})
                w = status.get("windows", {})
                if (w and not status["busy"] and not w["pending"]
                        and sum(ids.values()) + w["coalesced"] >= w["closed"] > 0):
                    break
                time.sleep(0.05)
            time.sleep(0.3)
    finally:
        daemon.stop()
    return got, status


def offline_r2(u: np.ndarray, y: np.ndarray, n_est: int, scfg: StreamConfig, seeds: list[int]) -> list[float]:
    """Free-run validation R^2 of cold offline ``identify`` runs (one per seed) on one window."""
    from streamid.engine.identification import identify
    from streamid.engine.validation import validate

    out = []
    for s in seeds:
        res = identify(u[:n_est], y[:n_est], scfg.coea_config(cold=True), np.random.default_rng(s))
        fr = validate(res.model, u[:n_est], y[:n_est], u[n_est:], y[n_est:]).fr_val
        out.append(float("-inf") if fr is None else fr)  # None: the free run diverged
    return out


def _rank(x: float, ref: list[float]) -> float:
    """Percentile rank of ``x`` among ``ref``: fraction below, ties counted half."""
    r = np.asarray(ref)
    return float((np.sum(r < x) + 0.5 * np.sum(r == x)) / r.size)


def mr_damper_max_speed(seed: int = 0, seeds: int = 6, selection: str = "fitness") -> dict[str, Any]:
    """Online (cold, then warm) vs offline (cold, ``seeds`` seeds) free-run validation R^2 per window."""
    import dataclasses

    from streamid.logs import bundled_log, read_log_arrays

    cfg = dataclasses.replace(MR_CONFIG, seed=seed, engine=(("selection", selection),) if selection != "fitness" else ())
    got, status = online_models(cfg)
    log = read_log_arrays(bundled_log("mr_damper.mcap"))
    u_all, y_all = log.inputs["velocity_cm_s"], log.outputs["force_N"]
    rows = []
    for up in got:
        w = up.window
        i0 = int(np.searchsorted(log.t_ns, w["t0_ns"]))
        if log.t_ns[i0] != w["t0_ns"]:
            raise RuntimeError(f"window {w['number']} starts at {w['t0_ns']} ns, not a sample time of the log")
        u, y = u_all[i0 : i0 + w["n_samples"]], y_all[i0 : i0 + w["n_samples"]]
        off = offline_r2(u, y, w["n_estimation"], cfg, [seed * 1000 + 17 * w["number"] + k for k in range(seeds)])
        rows.append({"number": w["number"], "warm": up.warm, "online": float(up.metrics["r2_fr_val"]),
                     "offline": off, "offline_median": float(np.median(off)),
                     "online_s": float(up.identification_s)})
    diffs = np.array([r["online"] - r["offline_median"] for r in rows])
    ranks = [_rank(r["online"], r["offline"]) for r in rows]
    median_diff = float(np.median(diffs)) if rows else float("nan")
    mean_rank = float(np.mean(ranks)) if rows else float("nan")
    return {
        "windows": rows,
        "windows_closed": int(status.get("windows", {}).get("closed", 0)),
        "windows_coalesced": int(status.get("windows", {}).get("coalesced", 0)),
        "models": len(got),
        "online_r2_fr_val": [r["online"] for r in rows],
        "offline_median_r2_fr_val": [r["offline_median"] for r in rows],
        "diff": diffs.tolist(),
        "median_diff": median_diff,
        "offline_spread_median": float(np.median([max(r["offline"]) - min(r["offline"]) for r in rows])) if rows else 0.0,
        "mean_rank": mean_rank,
        "windows_below_offline_min": int(sum(r["online"] < min(r["offline"]) for r in rows)),
        "expected_below_min_if_same": len(rows) / (seeds + 1),
        "online_mean": float(np.mean([r["online"] for r in rows])) if rows else float("nan"),
        "offline_mean": float(np.mean([np.mean(r["offline"]) for r in rows])) if rows else float("nan"),
        "online_min": min((r["online"] for r in rows), default=float("nan")),
        "tolerance": MATCH_TOL,
        "matches": bool(rows) and median_diff >= -MATCH_TOL and mean_rank >= MATCH_MIN_RANK,
        "selection": selection,
        "seeds": seeds,
    }


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench`` provider ``mr``: the MR damper log replayed at max speed into a daemon."""
    from benchmarks.kit import Measurement

    SECTION = "daemon"
    if not getattr(options, "quick", False):
        for sel in ("fitness", "fr_est"):
            mr = mr_damper_max_speed(int(getattr(options, "seed", 0)), selection=sel)
            case = f"MR damper log, max speed, selection {sel}"
            yield Measurement(SECTION, case, "R2 FR val online", "", tuple(mr["online_r2_fr_val"]),
                              f"{mr['models']} models for {mr['windows_closed']} windows (cold, then warm G=30)")
            yield Measurement(SECTION, case, "R2 FR val offline", "", tuple(mr["offline_median_r2_fr_val"]),
                              f"identify cold G=400, median of {mr['seeds']} seeds per window")
            yield Measurement(SECTION, case, "online - offline median", "", tuple(mr["diff"]),
                              f"mean rank {mr['mean_rank']:.2f} (0.5: same); "
                              f"{'matches' if mr['matches'] else 'does NOT match'} (benchmarks.mr)")

