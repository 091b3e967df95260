"""A forged model with an enormous version, against the shipped access control.

Real processes over real Zenoh on loopback: ``streamid router --zenoh-config
examples/zenoh/router.json5`` (authentication + access control, default deny),
``streamid daemon --zenoh-config examples/zenoh/daemon-via-router.json5`` behind it,
``streamid replay`` as user ``sensor``, ``streamid watch`` and a
:class:`ModelSubscriber` as user ``analyst``.  Once the daemon's first model is out,
forgers authenticated as ``sensor``, ``analyst`` and ``recorder`` put a copy of that
genuine model with ``"version": 10**12`` and a later origin epoch on
``streamid/mr_damper/model``, and a copy naming ``mr_damper`` on another stream's
model key: neither subscriber ever sees a forged version, and the daemon's next
models keep arriving.  The control: the same forgery put with the ``daemon``
credentials does reach a subscriber (what the ``daemon`` password is worth).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from conftest import STREAMID, endpoint
from test_security import FAST_DAEMON_TOML, Inbox, _counter_put, _pump, _settings, _wait_listening
from streamid.online import OnlineIdentifier, StreamConfig
from streamid.sim import get_device
from streamid.transport import Bus
from streamid.transport.client import ModelSubscriber
from streamid.transport.updates import ModelUpdate, parse_model_update

ROOT = Path(__file__).resolve().parents[1]
FORGED_VERSION = 10**12
ARRIVE_S = 30.0


class _Proc:
    """A CLI subprocess run from the repository root (the shipped files use relative paths)."""

    def __init__(self, *args: str) -> None:
        self.p = subprocess.Popen([*STREAMID, *args], cwd=ROOT, env=dict(os.environ, PYTHONUNBUFFERED="1"),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def stop(self, timeout_s: float = 15.0) -> tuple[str, str]:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
        try:
            return self.p.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.p.kill()
            return self.p.communicate(timeout=5)


@pytest.fixture
def secured() -> Iterator[tuple[str, list[_Proc]]]:
    ep = endpoint()
    procs: list[_Proc] = []
    try:
        router = _Proc("router", "--zenoh-config", "examples/zenoh/router.json5", "--listen", ep, "--duration", "120")
        procs.append(router)
        assert _wait_listening(ep, router.p, 30.0), "the router never listened on " + ep
        yield ep, procs
    finally:
        for pr in reversed(procs):
            pr.stop()


def _forged() -> bytes:
    """A well-formed model update of mr_damper (identified here) with an enormous version and a later origin."""
    t_ns, u, y = get_device("mr_damper").simulate_seconds(2.5, seed=5)
    ident = OnlineIdentifier(StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=5, neurons=3,
                                          max_lag_y=2, max_lag_u=2, population=8, min_r2_osa=-1e9, min_r2_fr=-1e9),
                             stream="mr_damper")
    ident.learn_many(t_ns, u, y, inputs=["velocity_cm_s"], outputs=["force_N"])
    up = next(up for up in ident.update_all() if up.accepted)
    assert up.document is not None
    doc = dict(up.document, version=FORGED_VERSION, origin={"daemon": "forger", "epoch_ns": time.time_ns() + 10**18})
    return json.dumps(doc).encode()


def test_shipped_acl_stops_a_forger_and_the_daemon_models_still_arrive(
        secured: tuple[str, list[_Proc]], tmp_path: Path) -> None:
    ep, procs = secured
    forged = _forged()
    assert parse_model_update(forged).version == FORGED_VERSION  # a subscriber would take it, were it delivered
    keys = ("streamid/mr_damper/model", "streamid/other/model")  # its own key, and another stream's key
    (tmp_path / "fast.toml").write_text(FAST_DAEMON_TOML)
    daemon = _Proc("daemon", "--zenoh-config", "examples/zenoh/daemon-via-router.json5", "--connect", ep,
                   "--no-rerun", "--config", str(tmp_path / "fast.toml"), "--stream", "mr_damper", "--duration", "100",
                   "-v")
    procs.append(daemon)
    seen: list[ModelUpdate] = []
    stop = threading.Event()
    puts = [0]

    def forge(role: str) -> None:
        with Bus(_settings(f"{role}.json5", connect=(ep,))) as bus:  # authenticated: the link opens
            pubs = [bus.publisher(k) for k in keys]
            for _ in range(3000):  # bounded: 60 s at most
                if stop.wait(0.02):
                    return
                for pub in pubs:
                    pub.put(forged)
                    puts[0] += 1

    forgers = [threading.Thread(target=forge, args=(r,), daemon=True) for r in ("sensor", "analyst", "recorder")]
    with Bus(_settings("analyst.json5", connect=(ep,))) as analyst, \
            ModelSubscriber(analyst, "mr_damper", seen.append, fetch_latest=False) as sub:
        watch = _Proc("watch", "--zenoh-config", "examples/zenoh/analyst.json5", "--connect", ep,
                      "--stream", "mr_damper", "--json", "--duration", "90")
        procs.append(watch)
        with Bus(_settings("sensor.json5", connect=(ep,))) as probe_bus:
            probe = probe_bus.publisher("streamid/mr_damper/samples")
            assert probe.wait_for_subscribers(ARRIVE_S), "the daemon never subscribed through the router"
        try:
            for t in forgers:  # the forgery is on the bus before the daemon's first model
                t.start()
            deadline = time.monotonic() + ARRIVE_S
            while puts[0] < 100 and time.monotonic() < deadline:
                time.sleep(0.02)
            replay = subprocess.run(
                [*STREAMID, "replay", "mr_damper", "--rate", "4", "--zenoh-config", "examples/zenoh/sensor.json5",
                 "--connect", ep, "--wait-subscribers", "15"],
                cwd=ROOT, capture_output=True, text=True, timeout=60)
            assert replay.returncode == 0, replay.stderr
            assert sub.wait_for_version(1, ARRIVE_S) is not None, "no genuine model reached the analyst"
            time.sleep(1.0)  # the last window's model
        finally:
            stop.set()
            for t in forgers:
                t.join(10)
        dout, derr = daemon.stop()
        wout, werr = watch.stop()
    published = sorted({int(w.split(" published")[0].rsplit("model v", 1)[1])
                        for w in derr.splitlines() if "identified, model v" in w})
    assert puts[0] > 300, "the forgers did not run"
    assert published, derr[-3000:]
    assert [u.version for u in seen] == published, (published, derr[-3000:])  # every genuine model, in order
    assert sub.errors == 0 and all(u.origin is not None and u.origin.daemon != "forger" for u in seen)
    docs = [json.loads(line) for line in wout.splitlines() if line.startswith("{")]  # --json: status events too
    shown = [d["version"] for d in docs if d.get("format") == "streamid.model-update/1"]
    assert shown == published, (wout, werr)
    assert str(FORGED_VERSION) not in wout

    # The control: the same forgery with the daemon's credentials gets through (keep that password to daemons).
    got: list[ModelUpdate] = []
    with Bus(_settings("analyst.json5", connect=(ep,))) as analyst, \
            ModelSubscriber(analyst, "mr_damper", got.append, fetch_latest=False), \
            Bus(_settings("daemon-via-router.json5", connect=(ep,))) as rogue:
        pub = rogue.publisher("streamid/mr_damper/model")
        deadline = time.monotonic() + ARRIVE_S
        while time.monotonic() < deadline and not any(u.version == FORGED_VERSION for u in got):
            pub.put(forged)
            time.sleep(0.05)
    assert any(u.version == FORGED_VERSION for u in got), "the control forgery never arrived: the test cannot fail"
    print(f"forged puts refused: {puts[0]}; genuine versions seen: {published}", file=sys.stderr)


def test_shipped_acl_lets_daemons_ask_versions_and_carries_rejected_challengers() -> None:
    """Through router.json5: a daemon's version query reaches another daemon's model queryable (recovery after
    lost state); rejected challengers flow from a daemon to analysts, and a sensor cannot forge one."""
    ep = endpoint()
    with Bus(_settings("router.json5", listen=(ep,))), \
            Bus(_settings("daemon-via-router.json5", connect=(ep,))) as old_life, \
            Bus(_settings("daemon-via-router.json5", connect=(ep,))) as new_life, \
            Bus(_settings("analyst.json5", connect=(ep,))) as analyst, \
            Bus(_settings("sensor.json5", connect=(ep,))) as sensor:
        old_life.queryable("streamid/r/model", lambda _k: b"served-v7")
        replies: list[tuple[str, bytes]] = []
        deadline = time.monotonic() + ARRIVE_S  # declarations propagate asynchronously
        while not replies and time.monotonic() < deadline:
            replies = new_life.get("streamid/r/model", timeout_s=0.5, all_replies=True)
        assert replies == [("streamid/r/model", b"served-v7")]
        assert sensor.get("streamid/r/model", timeout_s=0.5) == []  # sensors still cannot query models
        rejected = Inbox()
        analyst.subscribe("streamid/*/rejected", rejected)
        put_genuine = _counter_put(old_life, "streamid/r/rejected", b"challenger#")
        put_forged = _counter_put(sensor, "streamid/r/rejected", b"forged#")

        def both() -> None:
            put_genuine()
            put_forged()

        assert _pump(both, lambda: rejected.count(b"challenger#") >= 3)
        assert rejected.count(b"forged#") == 0
