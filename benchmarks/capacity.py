"""``streamid bench --only capacity``: how many streams one 2-core box serves, and the engine against record length.

Issue 38 item 4.  Every process is real and on loopback:

* **Streams per box.**  For each sample rate (200 Hz, 2 kHz, 20 kHz) and each stream count of its ladder,
  smallest first: ``streamid daemon`` with its default settings (10 s windows decided every second; only
  ``--listen`` on a free ``tcp/127.0.0.1`` port and ``--no-rerun``), a publisher process putting that many
  simulated streams in real time (the MR damper at 200 Hz and 2 kHz, the piezo at 20 kHz; batches of 1/20 s,
  BLOCK congestion control), and this process recording every decision (accepted models and rejected
  challengers) and sampling the daemon's resident memory.  All streams start at once, so their first (cold)
  runs queue up: the windows a stream loses before its first decision are counted apart from those it loses
  once served.  A count is *kept up with* when every stream was served (a model) and decided at least
  ``seconds - 35`` windows (issue 38's target: 40 decisions per stream in 75 s, the first window closing at
  10 s); the ladder stops at the first count whose streams were not all served.  The stricter figure, every
  window of the run decided, is the ``coalesced windows`` row (and how many of them after a stream's first
  decision).
  Per trial: decision latency p50/p99 (window closed -> decided, the daemon's clock), coalesced windows,
  decisions per stream, the median over streams of the served model's held-out free-run R^2, the daemon's
  peak RSS and its growth per stream over the idle daemon, and how many decisions were refreshes of the
  champion's weights (:mod:`streamid.online.refresh`) and how many coevolution runs.
* **Engine against record length.**  Each in a fresh process, on the 2 kHz MR damper: one cold *online update*
  of a window of 10k, 100k and 1M samples (what the daemon runs: the search on a bounded set of rows, 30 %
  held out; its held-out free-run R^2), and one offline ``identify`` of a record of that length with the same
  engine settings (``StreamConfig().coea_config(cold=True)``: the search on every row; free-run R^2 on the
  samples after): seconds, peak resident memory.  A length whose working
  memory (the daemon's own estimate) exceeds 60 % of the memory available is not run and says so.
* **A refresh's cost**: microseconds per new sample of the weights' blocked least squares.

``python -m benchmarks.capacity trial RATE STREAMS [--seconds S]`` runs one trial and prints its JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.kit import BenchOptions, Measurement
from benchmarks.load import _free_endpoint, _stop, paced_publish, proc_memory_mb

__all__ = ["CapacityPlan", "FULL", "QUICK", "bench", "capacity_measurements", "engine_length", "publish_main", "trial"]

SECTION = "capacity"


@dataclass(frozen=True)
class CapacityPlan:
    """What the section runs.

    ``ladders``: per sample rate (Hz), the stream counts to try, ascending (the ladder stops at the first count
    not kept up with). ``seconds``: each trial's length of real time. ``daemon_toml``: the daemon's
    configuration file ("": none, its defaults). ``engine_lengths``: record lengths of the engine's runs.
    """

    ladders: tuple[tuple[float, tuple[int, ...]], ...]
    seconds: float = 75.0
    engine_lengths: tuple[int, ...] = (10_000, 100_000, 1_000_000)
    offline_lengths: tuple[int, ...] = (10_000, 100_000, 1_000_000)
    engine_timeout_s: float = 900.0
    daemon_toml: str = ""
    seed: int = 0

    def __post_init__(self) -> None:
        for rate, counts in self.ladders:
            if not rate > 0 or not counts or list(counts) != sorted(counts) or counts[0] < 1:
                raise ValueError(f"a ladder is (rate_hz > 0, ascending stream counts >= 1); got {(rate, counts)!r}")
        if not self.seconds > 0:
            raise ValueError(f"seconds must be > 0; got {self.seconds!r}")


FULL = CapacityPlan(ladders=((200.0, (40, 80, 160)), (2000.0, (10, 20, 30, 40)), (20000.0, (1, 2, 4, 8))))
#: A smoke run (``--quick``), not for quoting: short windows, one small trial per rate, small records.
QUICK = CapacityPlan(ladders=((200.0, (2,)), (2000.0, (2,)), (20000.0, (1,))), seconds=12.0,
                     engine_lengths=(2_000, 6_000), offline_lengths=(2_000,), engine_timeout_s=300.0,
                     daemon_toml="[defaults]\nwindow_s = 2.0\nupdate_every_s = 1.0\ncold_generations = 40\n")


# --------------------------------------------------------------------------- data and the publisher
def _device_records(rate_hz: float, n_records: int, seconds: float, seed: int) -> tuple[str, str, int, list[Any]]:
    """(input name, output name, period_ns, [(u, y)]) of ``n_records`` simulated records at ``rate_hz``."""
    from streamid.sim import get_device
    from streamid.sim.mrdamper import MRDamperParams, simulate_mr_damper

    if rate_hz >= 10_000:  # the piezo is the 20 kHz device (decimated below that)
        dev = get_device("piezo")
        step = max(1, round(1e9 / rate_hz / dev.period_ns))
        recs = [dev.simulate_seconds(seconds * step, seed=seed + k) for k in range(n_records)]
        return dev.input_name, dev.output_name, dev.period_ns * step, [(u[::step].copy(), y[::step].copy())
                                                                       for _, u, y in recs]
    period = round(1e9 / rate_hz)
    params = MRDamperParams(period_ns=period)
    n = int(seconds * rate_hz)
    recs = [simulate_mr_damper(n, seed + k, params=params) for k in range(n_records)]
    return "velocity_cm_s", "force_N", period, [(u, y) for _, u, y in recs]


def publish_main(ep: str, streams: int, rate_hz: float, seconds: float, seed: int) -> None:
    """Publisher process body: ``streams`` streams ``cap<k>`` at ``rate_hz`` in real time for ``seconds``.

    A few distinct records (simulated once), each stream starting at its own offset in one of them, looped.
    Prints ``{"sent": {...}, "max_late_s": ...}``.
    """
    from streamid.wire.codec import SampleBatch

    n_rec = min(streams, 4)
    u_name, y_name, period, recs = _device_records(rate_hz, n_rec, 30.0 if rate_hz < 10_000 else 10.0, seed)
    batch = max(10, round(rate_hz / 20))
    n = len(recs[0][1]) // batch * batch
    per_rec = -(-streams // n_rec)
    offsets = [((k // n_rec) * (n // per_rec)) // batch * batch for k in range(streams)]
    names = [f"cap{k}" for k in range(streams)]

    def batch_of(k: int, j: int) -> SampleBatch:
        u, y = recs[k % n_rec]
        i0 = (offsets[k] + j * batch) % n
        return SampleBatch(names[k], j, j * batch * period, period, None, {u_name: u[i0:i0 + batch]},
                           {y_name: y[i0:i0 + batch]})

    sent, _, late = paced_publish(ep, names, int(seconds * rate_hz) // batch, batch, period, batch_of,
                                  ready=lambda: print("publishing", flush=True))
    print(json.dumps({"sent": sent, "max_late_s": late}), flush=True)


# --------------------------------------------------------------------------- one trial
def trial(rate_hz: float, streams: int, seconds: float, *, daemon_toml: str = "", seed: int = 0) -> dict[str, Any]:
    """One daemon, ``streams`` streams at ``rate_hz`` for ``seconds`` of real time (see the module docstring)."""
    from streamid.transport import Bus, ZenohSettings
    from streamid.transport.client import ModelSubscriber, latest_status

    ep = _free_endpoint()
    names = [f"cap{k}" for k in range(streams)]
    decisions: dict[str, list[dict[str, Any]]] = {n: [] for n in names}
    rss: list[float] = []
    with tempfile.TemporaryDirectory(prefix="streamid-capacity-") as tmp:
        argv = [sys.executable, "-m", "streamid", "daemon", "--listen", ep, "--no-rerun"]
        if daemon_toml:
            (Path(tmp) / "d.toml").write_text(daemon_toml, encoding="utf-8")
            argv += ["--config", str(Path(tmp) / "d.toml")]
        log = open(Path(tmp) / "daemon.log", "w+", encoding="utf-8")  # noqa: SIM115 - closed below
        daemon = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, text=True)
        procs: list[subprocess.Popen[str]] = [daemon]
        try:
            deadline = time.monotonic() + 60
            while "serving on" not in Path(log.name).read_text(encoding="utf-8") and time.monotonic() < deadline:
                if daemon.poll() is not None:
                    raise RuntimeError(f"the daemon exited: {Path(log.name).read_text(encoding='utf-8')[-2000:]}")
                time.sleep(0.1)
            time.sleep(1.0)
            idle_mb = proc_memory_mb(daemon.pid)[0]
            with Bus(ZenohSettings(connect=(ep,))) as bus:
                def on_update(up: Any) -> None:
                    if up.stream in decisions:
                        decisions[up.stream].append({
                            "accepted": bool(up.accepted), "version": up.version,
                            "update": str(up.document.get("update", "identified")),
                            "r2_fr_val": up.metrics.get("r2_fr_val"), "t_s": time.monotonic() - t_start,
                            "coalesced_before": int(up.window.get("coalesced_before", 0) or 0),
                            "identification_s": float(up.document.get("identification_s", math.nan) or math.nan),
                            "latency_s": (up.published_unix_ns - up.window_closed_unix_ns) / 1e9})

                t_start = time.monotonic()
                sub = ModelSubscriber(bus, "*", on_update, fetch_latest=False, include_rejected=True)
                code = f"from benchmarks.capacity import publish_main; publish_main({ep!r}, {streams}, {rate_hz}, " \
                       f"{seconds}, {seed})"
                pub = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
                procs.append(pub)
                end = time.monotonic() + seconds + 120
                while pub.poll() is None and time.monotonic() < end:
                    time.sleep(0.5)
                    if daemon.poll() is not None:
                        raise RuntimeError(f"the daemon exited: {Path(log.name).read_text(encoding='utf-8')[-2000:]}")
                    rss.append(proc_memory_mb(daemon.pid)[0])
                pub_out = _stop(pub, timeout_s=30)
                time.sleep(1.5)  # the last windows decided, their status published
                status = {n: latest_status(bus, n, timeout_s=2.0) or {} for n in names}
                sub.close()
                hwm = proc_memory_mb(daemon.pid)[1]
        finally:
            for p in reversed(procs):
                _stop(p)
            log.close()
    publisher = json.loads(pub_out.strip().splitlines()[-1])
    return _trial_figures(rate_hz, streams, seconds, decisions, status, rss, idle_mb, hwm, publisher)


def _trial_figures(rate_hz: float, streams: int, seconds: float, decisions: dict[str, list[dict[str, Any]]],
                   status: dict[str, dict[str, Any]], rss: list[float], idle_mb: float, hwm: float,
                   publisher: dict[str, Any]) -> dict[str, Any]:
    lat = [d["latency_s"] for ds in decisions.values() for d in ds]
    served = [n for n, ds in decisions.items() if any(d["accepted"] for d in ds)]
    fr = []
    for n in served:
        last = [d["r2_fr_val"] for d in decisions[n] if d["accepted"] and isinstance(d["r2_fr_val"], float)]
        if last:
            fr.append(last[-1])
    coalesced = {n: int((s.get("windows") or {}).get("coalesced", 0) or 0) for n, s in status.items()}
    counts = [len(ds) for ds in decisions.values()]
    after_first = sum(d["coalesced_before"] for ds in decisions.values() for d in ds[1:])
    first_t = [ds[0]["t_s"] for ds in decisions.values() if ds]
    first_run_s = [ds[0]["identification_s"] for ds in decisions.values() if ds]
    refresh_s = [d["identification_s"] for ds in decisions.values() for d in ds if d["update"] == "refreshed"]
    kinds = [d["update"] for ds in decisions.values() for d in ds]
    peak = max(rss) if rss else float("nan")
    return {
        "rate_hz": rate_hz, "streams": streams, "seconds": seconds,
        "served": len(served), "coalesced": sum(coalesced.values()),
        "coalesced_streams": sum(1 for v in coalesced.values() if v),
        "coalesced_after_first": after_first,
        "first_decision_max_s": max(first_t) if len(first_t) == streams else float("inf"),
        "first_decisions_s": sorted(round(t, 2) for t in first_t),
        "first_run_s_median": statistics.median(first_run_s) if first_run_s else float("nan"),
        "refresh_s_median": statistics.median(refresh_s) if refresh_s else float("nan"),
        "decisions_per_stream": counts,
        "decisions_min": min(counts) if counts else 0,
        "decisions_median": statistics.median(counts) if counts else 0,
        "latency_p50_s": float(np.quantile(lat, 0.5)) if lat else float("nan"),
        "latency_p99_s": float(np.quantile(lat, 0.99)) if lat else float("nan"),
        "latencies_s": lat,
        "served_fr_r2_median": statistics.median(fr) if fr else float("nan"),
        "refreshed": kinds.count("refreshed"), "identified": kinds.count("identified"),
        "rss_idle_mb": idle_mb, "rss_peak_mb": peak, "rss_hwm_mb": hwm,
        "rss_per_stream_mb": (peak - idle_mb) / streams if rss else float("nan"),
        "kept_up": len(served) == streams and min(counts, default=0) >= max(1, round(seconds - 35)),
        "publisher_max_late_s": publisher.get("max_late_s"),
        "degraded": sorted(n for n, s in status.items() if s.get("degraded")),
    }


# --------------------------------------------------------------------------- the engine against record length
#: The online engine lengths' common validation record: this many samples of the same simulated damper under
#: another seed's excitation, so the figures of 10k, 100k and 1M-sample windows compare on the same data.
COMMON_VAL_SAMPLES = 20_000
COMMON_VAL_SEED = 7919


def engine_main(n: int, seed: int, mode: str = "offline", record: int = 0, stream: str = "{}", offset: int = 0,
                common_samples: int = COMMON_VAL_SAMPLES) -> None:
    """Child process body: one cold identification of ``n`` samples (``mode``: ``online`` update of an ``n``-sample
    window, or ``offline`` ``identify``); prints its JSON figures.

    Online only: ``stream`` is a JSON object of :class:`~streamid.online.StreamConfig` fields changed from the
    defaults (e.g. ``{"neurons": 20}``, ``{"engine": {"search_rows": 0}}``: every row searched), ``offset`` where the
    window starts in the record and ``common_samples`` the common validation record's length.

    The samples are the start of one record of ``record`` samples (at least what the run needs): the caller passes
    the longest length it compares, so every length's data is the same excitation. The simulator's excitation is
    periodic over the record it draws, its lines 1 / (record length) apart, so records drawn at different lengths
    are different excitations: 10,000-sample windows scored 0.939 / 0.957 / 0.942 (seeds 0-2) on the common record
    when drawn as 12,000-sample records and 0.922 / 0.910 / 0.880 when cut from 102,000-sample records.
    """
    from streamid.engine import identify
    from streamid.engine.warmup import warm_up_kernels
    from streamid.daemon.config import stream_table_config
    from streamid.engine.validation import r2
    from streamid.online import OnlineIdentifier, StreamConfig

    if mode == "online":  # the changes checked first: a bad one fails before the record is simulated
        base = StreamConfig(window_samples=n, update_every_samples=n, max_pending_windows=2, seed=seed,
                            max_pending_bytes=2**31)
        cfg = stream_table_config("--stream", json.loads(stream), base)  # checked as a daemon's [streams.X] table

    warm_up_kernels()  # as the daemon does when it starts: the time below is the update's, not the kernels' loading

    if mode == "online":
        _, _, period, recs = _device_records(2000.0, 1, max(record, offset + n) / 2000.0 + 1.0, seed)
        u, y = recs[0][0][offset:offset + n].copy(), recs[0][1][offset:offset + n].copy()
        del recs
        ident = OnlineIdentifier(cfg, stream="engine")
        ident.learn_many(np.arange(n, dtype=np.int64) * period, u, y, inputs=["v"], outputs=["f"])
        _reset_peak_rss()
        before = proc_memory_mb_self()
        t0 = time.perf_counter()
        up = ident.update()
        seconds = time.perf_counter() - t0
        after = proc_memory_mb_self()
        fr = up.metrics.get("r2_fr_val", float("nan")) if up is not None else float("nan")
        common = float("nan")  # the same record for every length: another excitation of the same damper
        model = up.outcome.model if up is not None else None
        if model is not None:
            _, _, _, val = _device_records(2000.0, 1, common_samples / 2000.0, seed + COMMON_VAL_SEED)
            vu, vy = val[0]
            L = model.max_lag
            with np.errstate(all="ignore"):
                sim = model.simulate(vu, vy[:L])
            common = r2(vy[L:], sim[L:]) if np.all(np.isfinite(sim)) else float("-inf")
        print(json.dumps({"n": n, "seconds": seconds, "r2_fr": fr, "r2_fr_common": common, "peak_mb": after[1],
                          "peak_over_start_mb": after[1] - before[0], "kind": up.kind if up else None}), flush=True)
        return
    n_next = min(20_000, max(2_000, n // 5))
    _, _, _, recs = _device_records(2000.0, 1, (max(record, n) + n_next) / 2000.0 + 1.0, seed)
    u, y = recs[0][0][:n + n_next].copy(), recs[0][1][:n + n_next].copy()
    del recs
    _reset_peak_rss()
    before = proc_memory_mb_self()
    t0 = time.perf_counter()
    res = identify(u[:n], y[:n], StreamConfig().coea_config(cold=True), seed)
    seconds = time.perf_counter() - t0
    model = res.model
    L = model.max_lag
    un, yn = u[n - L:n + n_next], y[n - L:n + n_next]
    with np.errstate(all="ignore"):
        sim = model.simulate(un, yn[:L])
    try:
        fr = r2(yn[L:], sim[L:])
    except Exception:  # noqa: BLE001 - a diverged run is a figure too
        fr = float("nan")
    after = proc_memory_mb_self()
    print(json.dumps({"n": n, "seconds": seconds, "r2_fr": fr, "peak_mb": after[1],
                      "peak_over_start_mb": after[1] - before[0]}), flush=True)


def proc_memory_mb_self() -> tuple[float, float]:
    """(VmRSS, VmHWM) of this process in MB."""
    import os

    return proc_memory_mb(os.getpid())


def _reset_peak_rss() -> None:
    """Start this process's peak RSS (VmHWM) again from its current RSS (Linux ``clear_refs`` 5), so the peak
    measured after is that of the run, not of simulating its record; a kernel without it leaves the peak as it is."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")
    except OSError:
        pass


def engine_length(n: int, seed: int, timeout_s: float, mode: str = "offline", record: int = 0, stream: str = "{}",
                  offset: int = 0, common_samples: int = COMMON_VAL_SAMPLES) -> dict[str, Any]:
    """One :func:`engine_main` in a fresh process (skipped when its estimated memory does not fit); ``record``: the
    length of the record its samples start (the longest length compared); the rest as :func:`engine_main`'s."""
    from streamid.daemon.admission import identification_bytes
    from streamid.online import StreamConfig

    need = identification_bytes(n if mode == "online" else int(n / 0.7) + 1, 1, 1, StreamConfig())
    avail = _mem_available_bytes()
    if need > 0.6 * avail:
        return {"n": n, "skipped": f"needs ~{need >> 20} MiB by the daemon's estimate; {avail >> 20} MiB available"}
    code = (f"from benchmarks.capacity import engine_main; "
            f"engine_main({n}, {seed}, {mode!r}, {record}, {stream!r}, {offset}, {common_samples})")
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s, check=True)
    except subprocess.TimeoutExpired:
        return {"n": n, "skipped": f"not finished within {timeout_s:g} s"}
    except subprocess.CalledProcessError as exc:
        return {"n": n, "skipped": f"failed: {exc.stderr.strip()[-300:]}"}
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def _mem_available_bytes() -> int:
    with open("/proc/meminfo", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return 0


def refresh_us_per_sample(seed: int) -> float:
    """Microseconds per new sample of a refresh's blocked least squares (2 kHz MR damper, 2,000 new rows)."""
    from streamid.engine import identify
    from streamid.online import StreamConfig
    from streamid.online.refresh import accumulate, refreshed_weights

    _, _, period, recs = _device_records(2000.0, 1, 12.0, seed)
    u, y = recs[0]
    model = identify(u[:4000], y[:4000], StreamConfig().coea_config(cold=True).replace(generations=20), seed).model
    base = accumulate(None, model, u[:14_000], y[:14_000], 0, period, 30.0)
    times = []
    for _ in range(20):
        t0 = time.perf_counter()
        ne = accumulate(base, model, u[:16_000], y[:16_000], 0, period, 30.0)
        refreshed_weights(ne, 1e-9)
        times.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(times) / 2_000


# --------------------------------------------------------------------------- the section
def capacity_measurements(plan: CapacityPlan) -> Iterator[Measurement]:
    """Run ``plan``; one :class:`Measurement` per figure (see the module docstring)."""
    for rate, counts in plan.ladders:
        kept = 0
        tried = []
        for n in counts:
            r = trial(rate, n, plan.seconds, daemon_toml=plan.daemon_toml, seed=plan.seed)
            tried.append(f"{n}: {'kept up' if r['kept_up'] else 'not kept up'}")
            yield from _trial_rows(r)
            if r["kept_up"]:
                kept = n
            if r["served"] < n:
                break
        yield Measurement(SECTION, f"{rate:g} Hz, one daemon", "streams kept up", "streams", (float(kept),),
                          f"every stream served and >= {max(1, round(plan.seconds - 35))} decisions each in "
                          f"{plan.seconds:g} s; tried {', '.join(tried)}")
    runs = [(n, "online") for n in plan.engine_lengths] + [(n, "offline") for n in plan.offline_lengths]
    record = max(n for n, _ in runs) if runs else 0
    for n, mode in runs:
        e = engine_length(n, plan.seed, plan.engine_timeout_s, mode, record)
        case = (f"online cold update, {n}-sample window (2 kHz MR damper)" if mode == "online" else
                f"offline identify, {n} samples (2 kHz MR damper, online settings)")
        if "skipped" in e:
            yield Measurement(SECTION, case, "identification time", "s", (math.nan,), str(e["skipped"]))
            continue
        yield Measurement(SECTION, case, "identification time", "s", (e["seconds"],))
        yield Measurement(SECTION, case, "peak memory", "MB", (e["peak_mb"],),
                          f"process peak RSS; {e['peak_over_start_mb']:.0f} MB over its start")
        yield Measurement(SECTION, case, "R2 FR held out", "", (e["r2_fr"],),
                          "the window's newest 30 %" if mode == "online" else "free run on the samples after")
        if "r2_fr_common" in e:
            yield Measurement(SECTION, case, "R2 FR common record", "", (e["r2_fr_common"],),
                              f"free run on one {COMMON_VAL_SAMPLES}-sample record of another excitation, every length")
    yield Measurement(SECTION, "refresh of the champion's weights (2 kHz, 2,000 new rows)", "time per new sample",
                      "us", (refresh_us_per_sample(plan.seed),), "blocked least squares with forgetting, solve included")


def _trial_rows(r: dict[str, Any]) -> Iterable[Measurement]:
    case = f"{r['streams']} x {r['rate_hz']:g} Hz, {r['seconds']:g} s"
    lat = tuple(r["latencies_s"]) or (math.nan,)
    note = (f"p99 {r['latency_p99_s']:.3f} s; {r['refreshed']} refreshes, {r['identified']} coevolution runs")
    yield Measurement(SECTION, case, "decision latency p50", "s", (r["latency_p50_s"],), note, extra={"values_s": lat})
    yield Measurement(SECTION, case, "decision latency p99", "s", (r["latency_p99_s"],))
    yield Measurement(SECTION, case, "streams served", "streams", (float(r["served"]),), f"of {r['streams']}")
    yield Measurement(SECTION, case, "coalesced windows", "count", (float(r["coalesced"]),),
                      f"in {r['coalesced_streams']} streams; {r['coalesced_after_first']} after a stream's first decision")
    yield Measurement(SECTION, case, "last stream's first decision", "s", (r["first_decision_max_s"],),
                      "after the publisher began (all streams start at once; 10 s windows: >= 10 s)")
    yield Measurement(SECTION, case, "decisions per stream", "count", tuple(float(c) for c in r["decisions_per_stream"]),
                      f"min {r['decisions_min']}")
    yield Measurement(SECTION, case, "median served FR R2", "", (r["served_fr_r2_median"],),
                      "per stream its last accepted model's held-out free-run R2; median over streams")
    yield Measurement(SECTION, case, "RSS per stream", "MB", (r["rss_per_stream_mb"],),
                      f"(peak {r['rss_peak_mb']:.0f} MB - idle daemon {r['rss_idle_mb']:.0f} MB) / streams")
    yield Measurement(SECTION, case, "daemon peak RSS", "MB", (r["rss_peak_mb"],), f"VmHWM {r['rss_hwm_mb']:.0f} MB")


def bench(options: BenchOptions) -> Iterable[Measurement]:
    """The capacity section of ``streamid bench`` (``--quick``: :data:`QUICK`)."""
    plan = QUICK if options.quick else FULL
    return capacity_measurements(dataclasses.replace(plan, seed=options.seed))


def _main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.capacity")
    sub = p.add_subparsers(dest="what", required=True)
    t = sub.add_parser("trial")
    t.add_argument("rate_hz", type=float)
    t.add_argument("streams", type=int)
    t.add_argument("--seconds", type=float, default=75.0)
    t.add_argument("--config", default="", metavar="DAEMON.toml",
                   help="the daemon's configuration file (default: none, its defaults), e.g. a larger daemon.max_streams")
    e = sub.add_parser("engine")
    e.add_argument("n", type=int, nargs="+")
    e.add_argument("--timeout", type=float, default=900.0)
    e.add_argument("--mode", choices=("online", "offline"), default="online")
    e.add_argument("--seeds", type=int, nargs="+", default=[0],
                   help="one run per seed (the seed draws both the device's excitation and the engine's)")
    e.add_argument("--stream", default="{}", metavar="JSON",
                   help='online: StreamConfig fields changed, e.g. \'{"neurons": 20}\' or \'{"engine": {"search_rows": 0}}\'')
    e.add_argument("--offset", type=int, default=0, help="online: where each window starts in its seed's record")
    e.add_argument("--record", type=int, default=0,
                   help="the samples of each seed's record the windows are cut from (default: the longest n; the "
                        "excitation is periodic over its record, so records of other lengths are other excitations)")
    e.add_argument("--common-samples", type=int, default=COMMON_VAL_SAMPLES,
                   help=f"online: the common validation record's samples (default {COMMON_VAL_SAMPLES})")
    a = p.parse_args(argv)
    if a.what == "trial":
        r = trial(a.rate_hz, a.streams, a.seconds,
                  daemon_toml=Path(a.config).read_text(encoding="utf-8") if a.config else "")
        r.pop("latencies_s")
        print(json.dumps(r))
    else:
        for n in a.n:
            for seed in a.seeds:
                r = engine_length(n, seed, a.timeout, a.mode, a.record or max(a.n), a.stream, a.offset, a.common_samples)
                print(json.dumps({"seed": seed, **r}), flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_main(sys.argv[1:]))
