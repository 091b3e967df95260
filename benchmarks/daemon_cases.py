"""Daemon figures for ``streamid bench`` (and ``python -m benchmarks.daemon_cases`` for long soaks).

* **ingestion**: samples/s the daemon receives, decodes and windows (no
  identification) from a publisher in another process putting pre-encoded
  batches back to back over Zenoh on loopback (BLOCK congestion control).
* **update latency** and **soak**: the simulated 20 kHz piezo stream published
  in real time by another process; 0.5 s window updated every 1 s (warm G=30);
  latency = window closed -> model published; backlog (coalesced windows) and
  resident memory over the run.
* **cold vs warm**: time and validation R^2 of a cold run (G=400) and of warm
  updates (G=30) on consecutive windows of a stationary system (the piezo).
* **MR damper at max speed** (:mod:`benchmarks.mr`): the real MR
  damper log put back to back, every window identified (bounded queue of
  pending windows); the published models' free-run validation R^2 against
  offline cold ``identify`` runs (several seeds) with the same settings on the
  same windows, and whether they match (defined there).
* **load** (issue 6): eight 2 kHz streams plus the 20 kHz piezo log into one
  ``streamid daemon`` process for 2 minutes (:mod:`benchmarks.load`):
  samples lost, resident memory after warm-up, updates per stream.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from benchmarks.kit import BenchOptions, Measurement
from streamid.wire.codec import SampleBatch, encode
from streamid.daemon.config import DaemonConfig
from streamid.online import StreamConfig
from benchmarks.load import load_run, summary
from streamid.daemon.service import Daemon
from streamid.online import OnlineIdentifier, UpdateJob
from streamid.transport import ZenohSettings

__all__ = ["bench", "ingestion_rate", "realtime_run", "cold_vs_warm", "load_run"]

SECTION = "daemon"


def _free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _rss_mb() -> float:
    with open("/proc/self/statm", encoding="ascii") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _publisher(ep: str, device: str, batch: int, seconds: float, seed: int) -> subprocess.Popen[str]:
    """Start a publisher process putting pre-encoded batches back to back; it prints one JSON line."""
    code = f"from benchmarks.daemon_cases import _publish_main; _publish_main({ep!r}, {device!r}, {batch}, {seconds}, {seed})"
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)


def _replayer(ep: str, seconds: float) -> subprocess.Popen[str]:
    """Replay the bundled 20 kHz piezo log (20 s per pass) in real time for ``seconds``."""
    passes = max(1, int(np.ceil(seconds / 20.0)))
    extra = ["--end", f"{seconds:g}"] if seconds < 20.0 else ["--loop", str(passes)]
    return subprocess.Popen(
        [sys.executable, "-m", "streamid", "replay", "piezo_sim_20khz", "--connect", ep, "--json",
         "--wait-subscribers", "20", *extra],
        stdout=subprocess.PIPE, text=True,
    )


def _publish_main(ep: str, device: str, batch: int, seconds: float, seed: int) -> None:
    """Publisher process body: simulate ``device``, encode it all, then put it as fast as Zenoh takes it."""
    from streamid.sim import get_device
    from streamid.transport import Bus

    dev = get_device(device)
    t, u, y = dev.simulate_seconds(seconds, seed=seed)
    payloads = [
        encode(SampleBatch(device, k, int(t[i]), dev.period_ns, None, {dev.input_name: u[i : i + batch]},
                           {dev.output_name: y[i : i + batch]}))
        for k, i in enumerate(range(0, len(y) - batch + 1, batch))
    ]
    with Bus(ZenohSettings(connect=(ep,))) as bus:
        pub = bus.publisher(f"streamid/{device}/samples", block=True)
        pub.wait_for_subscribers(10.0)
        time.sleep(0.3)
        t0 = time.perf_counter()
        for p in payloads:
            pub.put(p)
        dt = time.perf_counter() - t0
        time.sleep(0.2)
    print(json.dumps({"samples": len(payloads) * batch, "seconds": dt}), flush=True)


def ingestion_rate(batch: int = 1000, seconds: float = 100.0, seed: int = 0) -> dict[str, float]:
    """Samples/s ingested by a daemon (no identification) from a back-to-back publisher process.

    ``seconds`` is the simulated stream length (mr_damper at 200 Hz -> 20k samples per 100 s),
    so the stream is the piezo at 20 kHz: ``seconds * 20000`` samples.
    """
    ep = _free_endpoint()
    cfg = DaemonConfig(defaults=StreamConfig(window_s=0.5, update_every_s=1.0))
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,)), identify=False).start()
    try:
        proc = _publisher(ep, "piezo", batch, seconds, seed)
        first: float | None = None
        deadline = time.monotonic() + 120
        want = int(seconds * 20000) // batch * batch
        got = 0
        while time.monotonic() < deadline:
            st = daemon.stream_status("piezo")
            if st is not None:
                got = int(st["samples_in"])
                if first is None and got > 0:
                    first = time.perf_counter()
                if got >= want:
                    break
            time.sleep(0.002)
        last = time.perf_counter()
        out, _ = proc.communicate(timeout=60)
        pubstat = json.loads(out.strip().splitlines()[-1])
        bad = daemon.stream_status("piezo")["bad_total"]  # type: ignore[index]
    finally:
        daemon.stop()
    if first is None or got < want:
        raise RuntimeError(f"ingestion bench: only {got} of {want} samples arrived")
    return {
        "samples_per_s": got / max(last - first, 1e-9),
        "publisher_samples_per_s": pubstat["samples"] / pubstat["seconds"],
        "samples": float(got),
        "bad": float(bad),
    }


def realtime_run(seconds: float = 30.0, seed: int = 0, warm_generations: int = 30, rrd: str | None = None) -> dict[str, Any]:
    """The bundled 20 kHz piezo log replayed in real time; 0.5 s windows every 1 s.

    Returns the steady-state latencies (window closed -> model published, from
    update 4 on: update 1 is the cold run and 2-3 wait out the windows that
    closed meanwhile), the cold run's time, backlog counters and resident memory.
    """
    ep = _free_endpoint()
    cfg = DaemonConfig(defaults=StreamConfig(window_s=0.5, update_every_s=1.0, warm_generations=warm_generations,
                                             seed=seed))
    viz = None
    if rrd is not None:
        from streamid.viz.rerun_view import Viz, VizSettings

        viz = Viz(VizSettings(rrd=rrd))
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,)), viz=viz).start()
    rss: list[tuple[float, float]] = []
    try:
        proc = _replayer(ep, seconds)
        t0 = time.monotonic()
        next_rss = 0.0
        while proc.poll() is None and time.monotonic() - t0 < seconds + 60:
            time.sleep(0.1)
            if time.monotonic() >= next_rss:
                next_rss = time.monotonic() + 1.0
                rss.append((time.monotonic() - t0, _rss_mb()))
        out, _ = proc.communicate(timeout=30)
        time.sleep(0.5)
        st = daemon.stream_status("piezo") or {}
        lat = daemon.latencies("piezo")
        decided = daemon.update_latencies("piezo")
    finally:
        daemon.stop()
    steady = [x for v, x in lat if v > 3]
    later = [m for t, m in rss if t >= seconds / 2]
    earlier = [m for t, m in rss if 10.0 < t < seconds / 2]  # after warm-up (imports, first cold run)
    every = [x for _, kind, x in decided][3:]  # every decision (accepted or not), after the cold run's backlog
    return {
        "latencies_s": steady,
        "decision_latencies_s": every,
        "decision_kinds": sorted({kind for _, kind, _ in decided}),
        "cold_latency_s": next((x for v, x in lat if v == 1), float("nan")),
        "within_0_5s": float(np.mean(np.asarray(steady) <= 0.5)) if steady else float("nan"),
        "versions": st["version"],
        "windows": st["windows"],
        "samples_in": st["samples_in"],
        "bad_total": st["bad_total"],
        "rss_mb": rss,
        "rss_growth": (max(later) / max(earlier) - 1.0) if later and earlier else float("nan"),
        "replay": json.loads(out.strip().splitlines()[-1]) if out.strip() else {},
    }


def cold_vs_warm(seed: int = 0, updates: int = 4, quick: bool = False) -> dict[str, Any]:
    """Cold (G=400) vs warm (G=30) on consecutive windows of the stationary piezo.

    The warm chain is an :class:`~streamid.online.OnlineIdentifier`'s own; each of its
    windows is also identified cold (``force_cold``) with the same seed for comparison.
    """
    from streamid.sim import get_device

    cfg = StreamConfig(window_s=0.5, update_every_s=1.0, seed=seed, cold_generations=100 if quick else 400,
                       max_pending_windows=updates + 2)
    dev = get_device("piezo")
    t, u, y = dev.simulate_seconds(1.0 + updates, seed=seed)
    ident = OnlineIdentifier(cfg, stream="piezo")
    ident.learn_many(t, u, y, inputs=[dev.input_name], outputs=[dev.output_name])
    job = ident.next_job()
    assert job is not None
    first = job.run()
    ident.finish(job, first)
    cold_t, cold_r2 = [first.seconds], [first.summary.metrics["r2_fr_val"]]  # type: ignore[union-attr]
    warm_t, warm_r2 = [], []
    for _ in range(updates):
        job = ident.next_job()
        if job is None:
            break
        warm = job.run()
        cold = UpdateJob(job.window, cfg, job.version, force_cold=True).run()
        ident.finish(job, warm)
        warm_t.append(warm.seconds)
        warm_r2.append(warm.summary.metrics["r2_fr_val"])  # type: ignore[union-attr]
        cold_t.append(cold.seconds)
        cold_r2.append(cold.summary.metrics["r2_fr_val"])  # type: ignore[union-attr]
    return {"cold_s": cold_t, "warm_s": warm_t, "cold_r2_fr_val": cold_r2, "warm_r2_fr_val": warm_r2,
            "cold_generations": cfg.cold_generations, "warm_generations": cfg.warm_generations}


def bench(options: BenchOptions) -> Iterable[Measurement]:
    """The daemon section of ``streamid bench``."""
    reps = 1 if options.quick else max(1, min(options.repeat, 3))
    rates = {b: [ingestion_rate(b, 25.0 if options.quick else 100.0, options.seed + i)["samples_per_s"]
                 for i in range(reps)] for b in (100, 1000)}
    for b, v in rates.items():
        yield Measurement(SECTION, f"ingestion, batches of {b}", "samples/s", "samples/s", tuple(v),
                          "decode + window, no identification; publisher in another process")
    rt = realtime_run(8.0 if options.quick else 60.0, options.seed)
    lat = rt["latencies_s"] or [float("nan")]
    yield Measurement(SECTION, "piezo 20 kHz real time, 0.5 s window / 1 s", "update latency", "s", tuple(lat),
                      "window closed -> model published, warm G=30, from update 4 on")
    yield Measurement(SECTION, "piezo 20 kHz real time, 0.5 s window / 1 s", "updates within 0.5 s", "%",
                      (100 * rt["within_0_5s"],), f"cold first update: {rt['cold_latency_s']:.2f} s")
    dec = rt["decision_latencies_s"] or [float("nan")]
    yield Measurement(SECTION, "piezo 20 kHz real time, 0.5 s window / 1 s", "decision latency", "s", tuple(dec),
                      f"window closed -> decided, every decision ({', '.join(rt['decision_kinds'])}), from the 4th; "
                      f"within 0.5 s: {100 * float(np.mean(np.asarray(dec) <= 0.5)):.0f} %")
    yield Measurement(SECTION, "piezo 20 kHz real time, 0.5 s window / 1 s", "windows coalesced", "count",
                      (float(rt["windows"]["coalesced"]),), f"of {rt['windows']['closed']} closed (first: cold run)")
    if not options.quick:
        yield Measurement(SECTION, "piezo 20 kHz real time, 0.5 s window / 1 s", "RSS growth 2nd half", "%",
                          (100 * rt["rss_growth"],), "peak resident memory, 2nd half vs 10 s..half")
    cw = cold_vs_warm(options.seed, 2 if options.quick else 4, options.quick)
    yield Measurement(SECTION, f"piezo cold G={cw['cold_generations']}", "update time", "s", tuple(cw["cold_s"]))
    yield Measurement(SECTION, f"piezo warm G={cw['warm_generations']}", "update time", "s", tuple(cw["warm_s"]))
    yield Measurement(SECTION, f"piezo cold G={cw['cold_generations']}", "R2 FR val", "", tuple(cw["cold_r2_fr_val"]))
    yield Measurement(SECTION, f"piezo warm G={cw['warm_generations']}", "R2 FR val", "", tuple(cw["warm_r2_fr_val"]))
    secs = 20.0 if options.quick else 120.0
    lr = load_run(secs, seed=options.seed)
    ls = summary(lr, min(30.0, secs / 4))
    case = f"load: 8 x 2 kHz + piezo 20 kHz, {secs:g} s"
    yield Measurement(SECTION, case, "samples lost", "count", (float(ls["samples_lost"]),),
                      f"of {ls['samples_sent']} sent, publisher max late {ls['publisher_max_late_s']:.3f} s")
    lo, hi = ls["rss_after_warmup_mb"]
    yield Measurement(SECTION, case, "daemon RSS after warm-up", "MB", (lo, hi),
                      f"spread {100 * ls['rss_spread']:.1f} %, peak (VmHWM) {ls['hwm_mb']:.1f} MB")
    yield Measurement(SECTION, case, "models per stream", "count", tuple(float(v) for v in ls["versions"].values()),
                      f"one window per second; coalesced {sorted(set(ls['coalesced'].values()))}")
    yield Measurement(SECTION, case, "longest time without a decision", "s",
                      tuple(ls["longest_without_decision_s"].values()), "per stream, after warm-up")


def _main(argv: list[str]) -> int:
    """``python -m benchmarks.daemon_cases soak SECONDS [RRD]`` | ``ingest BATCH`` | ``coldwarm`` | ``load SECONDS``."""
    what = argv[0] if argv else "soak"
    if what == "soak":
        r = realtime_run(float(argv[1]) if len(argv) > 1 else 300.0, rrd=argv[2] if len(argv) > 2 else None)
        lat = r["latencies_s"]
        print(json.dumps({k: v for k, v in r.items() if k not in ("latencies_s", "rss_mb")}))
        print("rss_mb:", [round(m, 1) for _, m in r["rss_mb"][:: max(1, len(r["rss_mb"]) // 20)]])
        if lat:
            q = np.quantile(lat, [0.5, 0.95, 0.99])
            print(f"latency s: median {q[0]:.3f} p95 {q[1]:.3f} p99 {q[2]:.3f} max {max(lat):.3f} n {len(lat)}; "
                  f"within 0.5 s: {100 * r['within_0_5s']:.1f} %")
    elif what == "ingest":
        print(json.dumps(ingestion_rate(int(argv[1]) if len(argv) > 1 else 1000)))
    elif what == "coldwarm":
        print(json.dumps(cold_vs_warm()))
    elif what == "load":
        secs = float(argv[1]) if len(argv) > 1 else 120.0
        r = load_run(secs)
        print(json.dumps({**summary(r, min(30.0, secs / 4)), "smaps": r["smaps"]}, indent=1))
        print("rss_mb:", [round(m, 1) for _, m in r["rss_mb"][:: max(1, len(r["rss_mb"]) // 24)]])
    return 0


if __name__ == "__main__":  # pragma: no cover
    threading.current_thread().name = "bench"
    sys.exit(_main(sys.argv[1:]))
