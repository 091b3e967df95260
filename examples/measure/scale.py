"""Scale figures of issue 15: streams per daemon in real time, several daemons sharing, failover times.

Every process is real (``streamid router``, ``streamid daemon`` with its default settings, a
publisher of 2 kHz streams, an observer of every decision), each on its own host of a
:mod:`tests.hosts` network: network namespaces (root and ``iproute2``) or plain loopback.

    python examples/measure/scale.py capacity DAEMONS STREAMS [STREAMS ...] [--net netns|loopback] [--seconds S]
    python examples/measure/scale.py failover KILLS [--net netns|loopback] [--streams N]

``capacity``: for each stream count, a fresh network: the router, DAEMONS daemons (no
``--stream``: they share), one publisher of that many streams (2 kHz, 100-sample batches,
paced in real time; piezo physics decimated), an observer.  After ``--warmup`` seconds
(the first 10 s window and its cold identification) it counts each stream's decisions
(accepted models on ``streamid/<s>/model`` plus rejected challengers on
``streamid/<s>/rejected``) for ``--seconds``.  The default stream settings decide one window
per second, so a stream is *kept up with* when it got at least 0.9 decisions per second;
the daemons keep up with the count when every stream is.

``failover``: two daemons, ``--streams`` streams; KILLS times (the two daemons in turn):
SIGKILL one, record for each stream it served the time from the kill to the survivor's
first decision on it (an accepted model, or a rejected challenger: the champion it took
over stayed), restart the killed daemon on its state directory and let it take its share
back.

Prints one JSON line per measurement.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
STREAMID = [sys.executable, "-m", "streamid"]
RATE_HZ = 2000.0
BATCH = 100


# --------------------------------------------------------------------------- processes run on hosts
def publish_main(ep: str, prefix: str, streams: int, seconds: float, rate_hz: float = RATE_HZ) -> None:
    """``streams`` streams ``<prefix><k>`` at ``rate_hz``, real time, until ``seconds`` have passed."""
    import numpy as np

    from streamid.sim import get_device
    from streamid.transport import Bus, ZenohSettings
    from streamid.wire.codec import SampleBatch, encode

    dev = get_device("piezo")
    step = max(1, round(1e9 / rate_hz / dev.period_ns))
    period = dev.period_ns * step
    sigs = []
    for k in range(min(streams, 4)):  # a few records (a 10 s piezo record takes ~1 s to simulate), shared below
        _, u, y = dev.simulate_seconds(max(10.0, 10.0 * RATE_HZ / rate_hz), seed=k)
        sigs.append((np.ascontiguousarray(u[::step]), np.ascontiguousarray(y[::step])))
    n = len(sigs[0][1]) // BATCH * BATCH
    per = -(-streams // len(sigs))  # streams sharing a record start at their own offset in it
    sigs = [(np.roll(u, -((k // len(sigs)) * (n // per))), np.roll(y, -((k // len(sigs)) * (n // per))))
            for k, (u, y) in ((k, sigs[k % len(sigs)]) for k in range(streams))]
    names = [f"{prefix}{k}" for k in range(streams)]
    with Bus(ZenohSettings(connect=(ep,))) as bus:
        pubs = [bus.publisher(f"streamid/{s}/samples", block=True) for s in names]
        for p in pubs:
            p.wait_for_subscribers(30.0)
        t0 = time.perf_counter()
        for j in range(int(seconds * rate_hz) // BATCH):
            due = t0 + (j + 1) * BATCH / rate_hz
            now = time.perf_counter()
            if due > now:
                time.sleep(due - now)
            i0 = (j * BATCH) % n
            for name, pub, (u, y) in zip(names, pubs, sigs, strict=True):
                pub.put(encode(SampleBatch(name, j, j * BATCH * period, period, None,
                                           {dev.input_name: u[i0:i0 + BATCH]}, {dev.output_name: y[i0:i0 + BATCH]})))


def observe_main(ep: str, seconds: float, out: str) -> None:
    """Record every decision (accepted model or rejected challenger) for ``seconds``, then write them as JSON."""
    from streamid.transport import Bus, ZenohSettings

    got: list[tuple[int, str, str, int, str]] = []

    def on(key: str, payload: bytes) -> None:
        doc = json.loads(payload)
        got.append((time.time_ns(), key.split("/")[2], doc["stream"], int(doc["version"]),
                    str((doc.get("origin") or {}).get("daemon"))))

    with Bus(ZenohSettings(connect=(ep,))) as bus:
        bus.subscribe("streamid/*/model", on)
        bus.subscribe("streamid/*/rejected", on)
        print("observing", flush=True)
        time.sleep(seconds)
    Path(out).write_text(json.dumps(got))


# --------------------------------------------------------------------------- orchestration
def _script(*args: object) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *map(str, args)]


def _start_daemon(host: Any, ep: str, state: Path, log: Path) -> Any:
    state.mkdir(parents=True, exist_ok=True)
    proc = host.run([*STREAMID, "daemon", "--connect", ep, "--no-rerun", "--state-dir", str(state), "-v"], log)
    m = proc.wait_for(r"as daemon (\w+)", 60.0)
    if m is None:
        raise RuntimeError(f"daemon did not start: {proc.text()[-2000:]}")
    proc.daemon_id = m.group(1)  # type: ignore[attr-defined]
    return proc


def _network(kind: str, n: int) -> Any:
    from hosts import netns_unavailable, open_network

    if kind == "netns" and (why := netns_unavailable()):
        raise SystemExit(f"network namespaces unavailable here: {why} (use --net loopback)")
    return open_network(kind, n)


def capacity(n_daemons: int, n_streams: int, kind: str, warmup_s: float, seconds_s: float) -> dict[str, Any]:
    from hosts import wait_listening

    tmp = Path(tempfile.mkdtemp(prefix="streamid-scale-"))
    total = warmup_s + seconds_s
    with _network(kind, n_daemons + 2) as net:
        ep = f"tcp/{net.router.address}:7447"
        router = net.router.run([*STREAMID, "router", "--listen", ep], tmp / "router.log")
        if not wait_listening(router, 20.0):
            raise RuntimeError(f"router did not listen: {router.text()}")
        daemons = [_start_daemon(net.hosts[i], ep, tmp / f"state{i}", tmp / f"daemon{i}.log") for i in range(n_daemons)]
        obs_file = tmp / "decisions.json"
        observer = net.hosts[n_daemons].run(_script("observe", ep, total + 5, obs_file), tmp / "observer.log")
        observer.wait_for("observing", 30.0)
        time.sleep(1.0 if n_daemons == 1 else 3.0)  # daemons joined (a lone daemon at once; others after settling)
        t0 = time.time_ns()
        pub = net.hosts[n_daemons + 1].run(_script("publish", ep, "scale", n_streams, total), tmp / "publisher.log")
        observer.popen.wait(timeout=total + 120)
        pub.stop()
        got = json.loads(obs_file.read_text()) if obs_file.exists() else []
        for d in daemons:
            d.stop()
    start = t0 + int(warmup_s * 1e9)
    rates = {f"scale{k}": 0.0 for k in range(n_streams)}
    served_by: dict[str, set[str]] = {s: set() for s in rates}
    for t, _kind, stream, _v, daemon in got:
        if t >= start and stream in rates:
            rates[stream] += 1 / seconds_s
            served_by[stream].add(daemon)
    kept = all(r >= 0.9 for r in rates.values())
    return {"measure": "capacity", "net": kind, "daemons": n_daemons, "streams": n_streams, "rate_hz": RATE_HZ,
            "window_s": 10.0, "update_every_s": 1.0, "kept_up": kept,
            "decisions_per_s_min": round(min(rates.values()), 3),
            "decisions_per_s_median": round(statistics.median(rates.values()), 3),
            "streams_per_daemon": {d.daemon_id: sum(d.daemon_id in v for v in served_by.values()) for d in daemons}}


def failover(kills: int, kind: str, n_streams: int, rate_hz: float) -> dict[str, Any]:
    from hosts import wait_listening

    tmp = Path(tempfile.mkdtemp(prefix="streamid-failover-"))
    times: list[float] = []
    total_s = 45.0 + kills * 30.0
    with _network(kind, 4) as net:
        ep = f"tcp/{net.router.address}:7447"
        router = net.router.run([*STREAMID, "router", "--listen", ep], tmp / "router.log")
        if not wait_listening(router, 20.0):
            raise RuntimeError(f"router did not listen: {router.text()}")
        daemons = [_start_daemon(net.hosts[i], ep, tmp / f"state{i}", tmp / f"daemon{i}.log") for i in range(2)]
        obs_file = tmp / "decisions.json"
        observer = net.hosts[2].run(_script("observe", ep, total_s, obs_file), tmp / "observer.log")
        observer.wait_for("observing", 30.0)
        pub = net.hosts[3].run(_script("publish", ep, "fo", n_streams, total_s, "--rate-hz", rate_hz),
                               tmp / "publisher.log")
        # the observer writes its file only at the end: follow the daemons' own logs to pace the kills
        time.sleep(35.0)  # both joined (join_after_s 10 s), first windows identified
        events: list[tuple[int, str, list[str]]] = []
        for k in range(kills):
            victim_i = k % 2
            victim = daemons[victim_i]
            served = _served(victim)
            t_kill = time.time_ns()
            victim.kill()
            events.append((t_kill, victim.daemon_id, served))
            time.sleep(8.0)
            daemons[victim_i] = _start_daemon(net.hosts[victim_i], ep, tmp / f"state{victim_i}",
                                              tmp / f"daemon{victim_i}.{k}.log")
            time.sleep(20.0)  # it buffers join_after_s (10 s), joins and takes its share back
        observer.popen.wait(timeout=total_s + 120)
        pub.stop()
        got = json.loads(obs_file.read_text()) if obs_file.exists() else []
        for d in daemons:
            d.stop()
    for t_kill, dead, streams in events:
        for s in streams:
            after = [t for t, _kind, stream, _v, d in got if stream == s and t > t_kill and d != dead]
            if after:
                times.append((min(after) - t_kill) / 1e9)
    return {"measure": "failover", "net": kind, "kills": kills, "streams": n_streams, "rate_hz": rate_hz,
            "moved_streams": len(times),
            "served_at_kill": [len(s) for _, _, s in events],
            "seconds": sorted(round(x, 3) for x in times),
            "median_s": round(statistics.median(times), 3) if times else None,
            "max_s": round(max(times), 3) if times else None}


def _served(proc: Any) -> list[str]:
    """The streams a daemon serves now, from its log (served / handed over lines)."""
    import re

    state: dict[str, bool] = {}
    for m in re.finditer(r"stream (\S+): (served by this daemon|handed over)", proc.text()):
        state[m.group(1)] = m.group(2).startswith("served")
    return sorted(s for s, on in state.items() if on)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    c = sub.add_parser("capacity")
    c.add_argument("daemons", type=int)
    c.add_argument("streams", type=int, nargs="+")
    c.add_argument("--net", choices=("netns", "loopback"), default="netns")
    c.add_argument("--warmup", type=float, default=30.0)
    c.add_argument("--seconds", type=float, default=30.0)
    f = sub.add_parser("failover")
    f.add_argument("kills", type=int)
    f.add_argument("--net", choices=("netns", "loopback"), default="netns")
    f.add_argument("--streams", type=int, default=4)
    f.add_argument("--rate-hz", type=float, default=200.0,
                   help="sample rate of the streams (default 200 Hz: one survivor keeps up with all of them)")
    pu = sub.add_parser("publish")
    pu.add_argument("ep")
    pu.add_argument("prefix")
    pu.add_argument("streams", type=int)
    pu.add_argument("seconds", type=float)
    pu.add_argument("--rate-hz", type=float, default=RATE_HZ)
    ob = sub.add_parser("observe")
    ob.add_argument("ep")
    ob.add_argument("seconds", type=float)
    ob.add_argument("out")
    a = p.parse_args(argv)
    if a.what == "publish":
        publish_main(a.ep, a.prefix, a.streams, a.seconds, a.rate_hz)
    elif a.what == "observe":
        observe_main(a.ep, a.seconds, a.out)
    elif a.what == "capacity":
        for n in a.streams:
            print(json.dumps(capacity(a.daemons, n, a.net, a.warmup, a.seconds)), flush=True)
    else:
        print(json.dumps(failover(a.kills, a.net, a.streams, a.rate_hz)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
