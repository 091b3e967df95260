"""Sharing on a bus without access control says so (issue 39, item 4).

A real ``streamid daemon`` (sharing on, discovery, a chosen id) on loopback Zenoh; a forger is a plain Zenoh
client session on the same endpoint, as anyone who reaches the router would be.  The forger answers the
stream's status queryable with a copy naming another daemon (``streamid status`` must show the conflict with
both daemons named) and declares one member token that outranks the daemon for the stream (the daemon must
warn, naming it, when it hands the stream over).  A daemon started with the shipped access control
(``examples/zenoh/daemon.json5``) does not warn at start.
"""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
from conftest import STREAMID, endpoint, stop_process, wait_until

from streamid.daemon.sharing import ranking
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.wire.codec import SampleBatch, encode

REPO = Path(__file__).resolve().parent.parent
CONFIG = """
[daemon]
join_after_s = 1.0
claim_settle_s = 0.3
status_every_s = 0.5
helper = false

[defaults]
window_s = 2.0
update_every_s = 1.0
cold_generations = 10
warm_generations = 3
neurons = 3
max_lag_y = 2
max_lag_u = 2
population = 8
min_r2_osa = -1e9
min_r2_fr = -1e9
challenger_margin = -1.0
"""
P_NS = 5_000_000


def _feed(ep: str, stream: str, stop: threading.Event) -> None:
    _, u, y = get_device("mr_damper").simulate_seconds(30.0, seed=3)
    with Bus(ZenohSettings(mode="client", connect=(ep,))) as bus:
        pub = bus.publisher(f"streamid/{stream}/samples", block=True)
        for k in range(6000):  # at most 60 s of 4x real time
            if stop.wait(50 * P_NS / 1e9 / 4):
                return
            idx = np.arange(k * 50, (k + 1) * 50) % len(y)
            pub.put(encode(SampleBatch(stream, k, 10**12 + k * 50 * P_NS, P_NS, None,
                                       {"velocity": u[idx]}, {"force": y[idx]})))


def test_unprotected_sharing_warns_at_start_and_at_a_forged_hand_over_and_status_shows_the_conflict(
        tmp_path: Path) -> None:
    ep = endpoint()
    state = tmp_path / "state"
    state.mkdir()
    (state / "daemon.identity").write_text(json.dumps({"format": "streamid.daemon-identity/1", "daemon": "alpha",
                                                       "last_epoch_ns": 0}))
    (tmp_path / "d.toml").write_text(CONFIG)
    log = tmp_path / "daemon.log"
    stream = "dev1"
    forged_id = next(f"z{i}" for i in range(1000) if ranking(stream, ["alpha", f"z{i}"])[0] == f"z{i}")
    stop = threading.Event()
    # the documented trusted-network variant: a router without access control, the daemon connected to it
    router = subprocess.Popen([*STREAMID, "router", "--listen", ep], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    with open(log, "w") as fh:
        proc = subprocess.Popen([*STREAMID, "daemon", "--connect", ep, "--config", str(tmp_path / "d.toml"),
                                 "--state-dir", str(state), "--no-rerun", "-v"], stdout=fh, stderr=fh, text=True)
    feeder = threading.Thread(target=_feed, args=(ep, stream, stop), daemon=True)
    try:
        with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as forger:
            feeder.start()
            real: list[bytes] = []
            assert wait_until(lambda: bool(real.extend(p for _, p in forger.get(f"streamid/{stream}/status", 0.5)) or real)
                         and b'"version":0' not in real[-1], 60), log.read_text()[-3000:]
            # 1. at start: the warning, naming the recipe
            text = log.read_text()
            assert "stream sharing on a bus without access control" in text and "router.json5" in text, text[-3000:]
            # 2. a forged status answer next to the real one: streamid status names both daemons
            doc = json.loads(real[-1])
            doc["daemon"]["origin"]["daemon"] = "forged"
            forger.queryable(f"streamid/{stream}/status", lambda _k: json.dumps(doc).encode())
            out: subprocess.CompletedProcess[str] | None = None
            for _ in range(5):  # declarations propagate asynchronously: ask again until both answer
                out = subprocess.run([*STREAMID, "status", "--connect", ep, "--stream", stream, "--timeout", "1.5"],
                                     capture_output=True, text=True, timeout=60)
                if out.returncode == 3:
                    break
            assert out is not None and out.returncode == 3, (out.returncode, out.stdout, out.stderr)
            rows = [ln for ln in out.stdout.splitlines() if ln.startswith(stream)]
            assert len(rows) == 2 and {r.split()[1] for r in rows} == {"alpha", "forged"}, out.stdout
            assert all("CONFLICT: 2 answers" in r and "alpha (epoch" in r and "forged (epoch" in r for r in rows), rows
            assert "CONFLICT" in out.stderr and "alpha" in out.stderr and "forged" in out.stderr, out.stderr
            # 3. one member token from anyone: the stream goes to it; the daemon says so as a WARNING naming it
            forger.liveliness_token(f"streamid/@daemons/{forged_id}/{time.time_ns()}")
            assert wait_until(lambda: f"handed over to daemon '{forged_id}', which never put a state" in log.read_text(),
                         30), log.read_text()[-3000:]
            assert "WARNING" in next(ln for ln in log.read_text().splitlines() if "which never put a state" in ln)
    finally:
        stop.set()
        feeder.join(10)
        for p in (proc, router):
            stop_process(p)


def test_a_daemon_reached_from_this_machine_only_does_not_warn() -> None:
    """The default daemon (README journey 2) listens on loopback alone: only this machine's processes reach it, so
    no warning; one that connects to a router or listens beyond loopback is reached by others."""
    import zenoh

    from streamid.daemon.share_link import reaches_others

    def cfg(**kw: str) -> zenoh.Config:
        c = zenoh.Config()
        for key, value in kw.items():
            c.insert_json5(key.replace("__", "/"), value)
        return c

    assert not reaches_others(cfg(listen__endpoints='["tcp/127.0.0.1:7447"]'))
    assert not reaches_others(cfg(listen__endpoints='["tcp/[::1]:7447"]'))
    assert reaches_others(cfg(listen__endpoints='["tcp/127.0.0.1:7447"]', connect__endpoints='["tcp/127.0.0.1:7448"]'))
    assert reaches_others(cfg(listen__endpoints='["tcp/0.0.0.0:7447"]'))
    assert reaches_others(cfg(listen__endpoints='["tcp/192.0.2.10:7447"]'))
    assert reaches_others(zenoh.Config())  # Zenoh's own default listens on every interface
    proc = subprocess.run([*STREAMID, "daemon", "--listen", endpoint(), "--no-rerun", "--duration", "1.5", "-v"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "daemon started" in proc.stderr and "without access control" not in proc.stderr, proc.stderr[-3000:]


def test_a_daemon_with_the_shipped_access_control_does_not_warn(tmp_path: Path) -> None:
    proc = subprocess.run([*STREAMID, "daemon", "--zenoh-config", "examples/zenoh/daemon.json5", "--listen", endpoint(),
                           "--no-rerun", "--duration", "1.5", "-v"], capture_output=True, text=True, timeout=60,
                          cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "daemon started" in proc.stderr and "without access control" not in proc.stderr, proc.stderr[-3000:]
