"""The load run of issue 6: eight 2 kHz streams plus the 20 kHz piezo log into one ``streamid daemon`` process.

Three processes on loopback, all real:

* ``streamid daemon`` (the CLI, ``--no-rerun``), listening on a free
  ``tcp/127.0.0.1`` port, discovering the streams; 0.5 s windows updated every
  1 s of stream time (cold G=400, then warm G=30), two worker threads;
* a publisher of ``streams`` streams at ``rate_hz`` (piezo physics, decimated),
  paced in real time, 100-sample batches, BLOCK congestion control;
* ``streamid replay piezo_sim_20khz --loop`` (the bundled 20 kHz log, 200-sample
  batches, real time).

Meanwhile this process samples the daemon's resident memory from
``/proc/<pid>/status`` every ``sample_every_s``, records every model message,
and finally queries every stream's status.  :func:`load_run` returns the
figures; ``tests/test_load.py`` asserts on them and ``streamid bench`` (daemon
section) reports them.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from streamid.wire.codec import SampleBatch, encode
from streamid.transport import ZenohSettings

__all__ = ["load_run", "multi_publish_main", "proc_memory_mb", "resident_by_mapping", "summary"]

DAEMON_TOML = """
[daemon]
workers = 2
status_every_s = 1.0
retain_memory = {retain}

[defaults]
window_s = 0.5
update_every_s = 1.0
seed = {seed}
"""


def proc_memory_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of process ``pid`` in MB."""
    got = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith(("VmRSS:", "VmHWM:")):
                got[line[:5]] = int(line.split()[1]) * 1024 / 1e6
    return got["VmRSS"], got["VmHWM"]


def resident_by_mapping(pid: int, top: int = 8) -> dict[str, float]:
    """Resident MB of process ``pid`` by mapping: heap, anonymous, and the largest files."""
    sizes: dict[str, float] = {}
    name = ""
    with open(f"/proc/{pid}/smaps", encoding="utf-8", errors="replace") as fh:
        for line in fh:
            head = line.split()
            if not head:
                continue
            if "-" in head[0] and len(head) >= 5 and not head[0].endswith(":"):
                name = Path(head[5]).name if len(head) > 5 else "[anonymous]"
            elif head[0] == "Rss:":
                sizes[name] = sizes.get(name, 0.0) + int(head[1]) / 1024
    ranked = sorted(sizes.items(), key=lambda kv: -kv[1])
    out = dict(ranked[:top])
    out["(other)"] = sum(v for _, v in ranked[top:])
    return {k: round(v, 1) for k, v in out.items()}


def paced_publish(ep: str, names: list[str], rounds: int, batch: int, period_ns: int,
                  batch_of: Callable[[int, int], SampleBatch], ready: Callable[[], None] | None = None,
                  ) -> tuple[dict[str, int], float, float]:
    """Put one batch of ``batch`` samples per stream every ``batch * period_ns`` of real time, ``rounds`` times
    (``batch_of(k, j)``: stream ``k``'s batch of round ``j``), on ``streamid/<name>/samples`` over a session connected to ``ep``, once every
    publisher has a subscriber (then ``ready()``). Returns the samples sent per stream, the seconds it took and the
    largest lateness of a round (a publisher that cannot keep up shows it)."""
    from streamid.transport import Bus

    sent = dict.fromkeys(names, 0)
    late = 0.0
    with Bus(ZenohSettings(connect=(ep,))) as bus:
        pubs = [bus.publisher(f"streamid/{s}/samples", block=True) for s in names]
        for p in pubs:
            p.wait_for_subscribers(30.0)
        if ready is not None:
            ready()
        t0 = time.perf_counter()
        for j in range(rounds):
            due = t0 + (j + 1) * batch * period_ns / 1e9
            now = time.perf_counter()
            if due > now:
                time.sleep(due - now)
            else:
                late = max(late, now - due)
            for k, (name, pub) in enumerate(zip(names, pubs, strict=True)):
                pub.put(encode(batch_of(k, j)))
                sent[name] += batch
        dt = time.perf_counter() - t0
        time.sleep(0.3)
    return sent, dt, late


def multi_publish_main(ep: str, streams: int, rate_hz: float, seconds: float, batch: int, seed: int) -> None:
    """Publisher process body: ``streams`` streams at ``rate_hz``, real time; prints sent counts and lateness."""
    from streamid.sim import get_device

    dev = get_device("piezo")
    step = max(1, round(1e9 / rate_hz / dev.period_ns))
    period = dev.period_ns * step
    sigs = []
    for k in range(streams):
        _, u, y = dev.simulate_seconds(min(seconds, 10.0), seed=seed + k)
        sigs.append((u[::step].copy(), y[::step].copy()))
    n = len(sigs[0][1]) // batch * batch
    names = [f"load{k}" for k in range(streams)]

    def batch_of(k: int, j: int) -> SampleBatch:
        u, y = sigs[k]
        i0 = (j * batch) % n
        return SampleBatch(names[k], j, j * batch * period, period, None, {dev.input_name: u[i0 : i0 + batch]},
                           {dev.output_name: y[i0 : i0 + batch]})

    sent, dt, late = paced_publish(ep, names, int(seconds * 1e9 / period) // batch, batch, period, batch_of)
    print(json.dumps({"sent": sent, "seconds": dt, "max_late_s": late}), flush=True)


def _free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _stop(proc: subprocess.Popen[str], sig: int = signal.SIGINT, timeout_s: float = 20.0) -> str:
    """Stop a child we started (signal, then kill after the timeout); returns its stdout."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate(timeout=10)
    return out or ""


def _sent(pub_out: str, rep_out: str) -> dict[str, Any]:
    """Samples sent per stream, from the publisher's and the replay's last JSON lines ({} if one is missing)."""
    try:
        publisher = json.loads(pub_out.strip().splitlines()[-1])
        replay = json.loads(rep_out.strip().splitlines()[-1])
        return {**publisher["sent"], "piezo": replay["samples"]}
    except (IndexError, ValueError, KeyError, TypeError):
        return {}


def _settled_status(bus: Any, names: list[str], sent: dict[str, Any], bound_s: float) -> dict[str, dict[str, Any]]:
    """Each stream's status once the last windows are identified and their status published: asked of the daemon
    (its status now) until every stream has all its samples sent in, nothing pending and nothing being identified,
    at most ``bound_s`` (then the statuses as they are)."""
    from streamid.transport.client import latest_status

    deadline = time.monotonic() + bound_s
    while True:
        status = {n: latest_status(bus, n, timeout_s=2.0) or {} for n in names}
        if all(st and n in sent and st.get("samples_in", 0) >= sent[n] and not st.get("busy")
               and not st.get("windows", {}).get("pending") for n, st in status.items()):
            return status
        if time.monotonic() >= deadline:
            return status
        time.sleep(0.1)


def load_run(seconds: float = 120.0, streams: int = 8, rate_hz: float = 2000.0, seed: int = 0,
             sample_every_s: float = 0.5, retain_memory: bool = True) -> dict[str, Any]:
    """Run the load; returns per-stream counters, model times, memory series and publisher lateness.

    Keys: ``per_stream`` {name: {sent, ingested, versions, windows, bad_total, degraded, model_t}} (``model_t``:
    when each decision arrived, champions and rejected challengers),
    ``rss_mb`` [(t_s, MB)], ``hwm_mb`` (peak RSS of the daemon), ``publisher`` (its report),
    ``replay`` (the replayer's report), ``seconds``, ``smaps`` (the daemon's resident memory by mapping
    at the end, MB).  ``retain_memory=False`` runs the daemon with glibc's default allocator behaviour.
    """
    from streamid.transport.client import ModelSubscriber
    from streamid.transport import Bus

    ep = _free_endpoint()
    names = [f"load{k}" for k in range(streams)] + ["piezo"]
    models: dict[str, list[float]] = {n: [] for n in names}
    rss: list[tuple[float, float]] = []
    hwm = 0.0
    with tempfile.TemporaryDirectory(prefix="streamid-load-") as tmp:
        cfg = Path(tmp) / "load.toml"
        cfg.write_text(DAEMON_TOML.format(seed=seed, retain=str(retain_memory).lower()), encoding="utf-8")
        log = open(Path(tmp) / "daemon.log", "w+", encoding="utf-8")  # noqa: SIM115 - closed below
        daemon = subprocess.Popen([sys.executable, "-m", "streamid", "daemon", "--config", str(cfg), "--listen", ep,
                                   "--no-rerun"], stdout=log, stderr=subprocess.STDOUT, text=True)
        procs: list[subprocess.Popen[str]] = [daemon]
        try:
            connect = ZenohSettings(connect=(ep,))
            with Bus(connect) as bus:
                t0 = time.monotonic()
                # every decision (a new champion, or a challenger rejected): the stream is being served
                sub = ModelSubscriber(bus, "*", lambda up: models.setdefault(up.stream, []).append(
                    time.monotonic() - t0), fetch_latest=False, include_rejected=True)
                code = (f"from benchmarks.load import multi_publish_main; "
                        f"multi_publish_main({ep!r}, {streams}, {rate_hz}, {seconds}, 100, {seed})")
                multi = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
                procs.append(multi)
                passes = max(1, int(np.ceil(seconds / 20.0)))
                extra = ["--end", f"{seconds:g}"] if seconds < 20.0 else ["--loop", str(passes)]
                piezo = subprocess.Popen(
                    [sys.executable, "-m", "streamid", "replay", "piezo_sim_20khz", "--connect", ep, "--json",
                     "--wait-subscribers", "30", *extra], stdout=subprocess.PIPE, text=True)
                procs.append(piezo)
                deadline = time.monotonic() + seconds + 120
                while (multi.poll() is None or piezo.poll() is None) and time.monotonic() < deadline:
                    time.sleep(sample_every_s)
                    if daemon.poll() is not None:
                        log.seek(0)
                        raise RuntimeError(f"the daemon exited during the load run: {log.read()[-2000:]}")
                    now_rss, hwm = proc_memory_mb(daemon.pid)
                    rss.append((time.monotonic() - t0, now_rss))
                smaps = resident_by_mapping(daemon.pid)
                pub_out = _stop(multi, signal.SIGTERM, 30)
                rep_out = _stop(piezo, signal.SIGTERM, 30)
                status = _settled_status(bus, names, _sent(pub_out, rep_out), 1.5)
                sub.close()
        finally:
            for p in reversed(procs):
                _stop(p)
            log.close()
    publisher = json.loads(pub_out.strip().splitlines()[-1])
    replay = json.loads(rep_out.strip().splitlines()[-1])
    sent = _sent(pub_out, rep_out)
    return {
        "seconds": seconds,
        "per_stream": {
            n: {"sent": sent.get(n), "ingested": st.get("samples_in"), "versions": st.get("version"),
                "windows": st.get("windows"), "identifications": st.get("identifications"),
                "bad_total": st.get("bad_total"), "degraded": st.get("degraded"),
                "degraded_reason": st.get("degraded_reason"), "decisions": st.get("decisions"),
                "drifts": st.get("drifts"), "model_t": models.get(n, [])}
            for n, st in status.items()
        },
        "rss_mb": rss,
        "hwm_mb": hwm,
        "smaps": smaps,
        "publisher": publisher,
        "replay": {k: replay.get(k) for k in ("messages", "samples", "timing_error_us", "problem")},
    }


def summary(r: dict[str, Any], warmup_s: float) -> dict[str, Any]:
    """The figures of a :func:`load_run`: loss, memory spread after ``warmup_s``, models per stream."""
    after = [m for t, m in r["rss_mb"] if t >= warmup_s]
    per = r["per_stream"]
    gaps = {}
    for n, s in per.items():
        ts = [t for t in s["model_t"] if t >= warmup_s]
        gaps[n] = max(np.diff([warmup_s, *ts]).tolist()) if ts else float("inf")
    return {
        "samples_sent": sum(s["sent"] or 0 for s in per.values()),
        "samples_lost": sum((s["sent"] or 0) - (s["ingested"] or 0) for s in per.values()),
        "rss_after_warmup_mb": (min(after), max(after)) if after else None,
        "rss_spread": max(after) / min(after) - 1.0 if after else float("nan"),
        "hwm_mb": r["hwm_mb"],
        "versions": {n: s["versions"] for n, s in per.items()},
        "coalesced": {n: (s["windows"] or {}).get("coalesced") for n, s in per.items()},
        "longest_without_decision_s": gaps,
        "publisher_max_late_s": r["publisher"]["max_late_s"],
        "replay_timing_error_us": r["replay"]["timing_error_us"],
    }


if __name__ == "__main__":  # pragma: no cover - ``python -m benchmarks.load [SECONDS] [--default-malloc]``
    secs = float(sys.argv[1]) if len(sys.argv) > 1 else 120.0
    res = load_run(secs, retain_memory="--default-malloc" not in sys.argv)
    print(json.dumps({**summary(res, min(30.0, secs / 4)), "smaps": res["smaps"]}, indent=1))
    print("rss_mb:", [round(m, 1) for _, m in res["rss_mb"][:: max(1, len(res["rss_mb"]) // 40)]])
