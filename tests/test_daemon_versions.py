"""Versions a subscriber can trust: daemon identity and epoch, recovery from damaged or lost state.

Unit level (real files in a temporary directory): the identity file, the scan of
damaged state files, the quarantine's bound.  End to end (a real ``streamid
daemon`` subprocess SIGKILLed, its state file damaged, restarted; a real
:class:`ModelSubscriber` and ``streamid watch`` over real Zenoh on loopback):
:func:`test_restart_after_damaged_state_never_reuses_a_version`.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import STREAMID, endpoint

from streamid.daemon.identity import IDENTITY_FILE, IDENTITY_FORMAT, Origin, daemon_origin
from streamid.daemon.state_store import KEEP_QUARANTINED, StateStore
from streamid.daemon.versions import MAX_VERSION, VersionKeeper, highest_version_in
from streamid.online import OnlineIdentifier, StreamConfig
from streamid.online.snapshot import StreamState
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber
from streamid.transport.updates import ModelUpdate
from streamid.wire.codec import SampleBatch, encode


# --------------------------------------------------------------------------- identity and epoch
def test_identity_is_stable_per_state_dir_and_epochs_increase(tmp_path: Path) -> None:
    a = daemon_origin(tmp_path, now_ns=1_000)
    b = daemon_origin(tmp_path, now_ns=2_000)
    assert a.daemon == b.daemon and len(a.daemon) == 16
    assert (a.epoch_ns, b.epoch_ns) == (1_000, 2_000)
    (tmp_path / f".{IDENTITY_FILE}.abc123.tmp").write_text("{")  # a temporary of a writer killed mid-write
    # a wall clock stepped back: the epoch still moves forward for this state directory
    c = daemon_origin(tmp_path, now_ns=500)
    assert c.daemon == a.daemon and c.epoch_ns == 2_001
    doc = json.loads((tmp_path / IDENTITY_FILE).read_text())
    assert doc == {"format": IDENTITY_FORMAT, "daemon": a.daemon, "last_epoch_ns": 2_001}
    assert sorted(p.name for p in tmp_path.iterdir()) == [IDENTITY_FILE]  # the temporary removed
    # another state directory, or none: another daemon
    (tmp_path / "other").mkdir()
    assert daemon_origin(tmp_path / "other", now_ns=1).daemon != a.daemon
    assert daemon_origin(None, now_ns=1).daemon != daemon_origin(None, now_ns=1).daemon
    # the identity file is never taken for a stream's state
    assert StateStore(tmp_path).streams() == []


@pytest.mark.parametrize("text", ["", "{not json", '{"format": "x"}', '{"format": "streamid.daemon-identity/1", '
                                  '"daemon": "bad id with spaces"}', "\x00" * 5000])
def test_damaged_identity_file_gets_a_new_identity_with_a_warning(
        tmp_path: Path, text: str, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / IDENTITY_FILE).write_text(text)
    with caplog.at_level(logging.WARNING, logger="streamid.daemon.identity"):
        o = daemon_origin(tmp_path, now_ns=7)
    assert o.epoch_ns == 7 and len(o.daemon) == 16
    assert "starting under a new identity" in caplog.text and str(tmp_path / IDENTITY_FILE) in caplog.text
    assert json.loads((tmp_path / IDENTITY_FILE).read_text())["daemon"] == o.daemon  # replaced


def test_identity_name_held_by_a_directory_is_moved_aside_and_the_identity_written(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Was: a directory there made every identity write fail for ever (issue 52: quarantined, ERROR).  An identity
    that cannot be written at all (a full disk) is tests/test_full_disk.py's."""
    d = tmp_path / "ro"
    d.mkdir()
    (d / IDENTITY_FILE).mkdir()
    with caplog.at_level(logging.WARNING):
        o = daemon_origin(d, now_ns=42)
    assert o.epoch_ns == 42 and o.daemon
    assert "was a directory, not a regular file; moved aside" in caplog.text
    assert json.loads((d / IDENTITY_FILE).read_text())["daemon"] == o.daemon
    assert [q.is_dir() for q in d.glob(f"{IDENTITY_FILE}.quarantined-*")] == [True]


# --------------------------------------------------------------------------- damaged state files
def _state_text(version: int) -> str:
    return StreamState("s", version, {"dt": 1}, {"format": "streamid.model-update/1", "stream": "s",
                                                  "version": version}, json.dumps({"pop": [1, 2, 3]})).to_json()


@pytest.mark.parametrize("damage", ["cut", "flip", "zeros-after", "garbage-before"])
def test_highest_version_is_read_from_a_damaged_state_file(tmp_path: Path, damage: str) -> None:
    text = _state_text(417).encode()
    p = tmp_path / "s.json"
    if damage == "cut":
        raw = text[: text.index(b'"signature"')]  # cut after the first "version"
    elif damage == "flip":
        raw = bytes([text[0] ^ 0xFF]) + text[1:]  # not UTF-8, not JSON any more
    elif damage == "zeros-after":
        raw = text[: len(text) // 2] + b"\x00" * 100
    else:
        raw = os.urandom(300) + text
    p.write_bytes(raw)
    with pytest.raises(Exception):
        json.loads(raw)
    assert highest_version_in(p) == 417


def test_version_scan_ignores_what_is_not_a_version(tmp_path: Path) -> None:
    p = tmp_path / "x"
    p.write_bytes(b'{"version": 3.5, "version": 1e9, "x_version": 99, "version":"12", '
                  b'"version": 123456789012345678901234, "version": %d, "version": 8}' % (MAX_VERSION + 1))
    assert highest_version_in(p) == 8
    assert highest_version_in(tmp_path / "missing") is None
    p.write_bytes(b"no versions here")
    assert highest_version_in(p) is None


def test_quarantined_files_are_listed_newest_first_and_bounded(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    moved = []
    for v in range(KEEP_QUARANTINED + 3):
        store.path("s").write_text("damaged " + _state_text(v + 1))
        q = store.quarantine("s")
        assert q is not None and not store.path("s").exists()
        moved.append(q)
    kept = store.quarantined("s")
    assert kept == moved[::-1][:KEEP_QUARANTINED]  # the newest, newest first; the rest deleted
    assert not any(p.exists() for p in moved[: len(moved) - KEEP_QUARANTINED])
    assert store.quarantined("other") == [] and store.streams() == []
    assert highest_version_in(kept[0]) == KEEP_QUARANTINED + 3


# --------------------------------------------------------------------------- end to end: SIGKILL, damage, restart
FAST_TOML = """
[daemon]
status_every_s = 0.2
[defaults]
window_samples = 400
update_every_samples = 200
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
P_NS = 5_000_000  # 200 Hz
BATCH = 50


def _publish(ep: str, stop: threading.Event) -> None:
    """The simulated MR damper on streamid/mr_damper/samples, 4x real time, until ``stop`` (at most 10 min)."""
    _, u, y = get_device("mr_damper").simulate_seconds(30.0, seed=3)
    with Bus(ZenohSettings(mode="client", connect=(ep,))) as bus:
        pub = bus.publisher("streamid/mr_damper/samples", block=True)
        for k in range(48_000):
            if stop.wait(BATCH * P_NS / 1e9 / 4):
                return
            idx = (np.arange(k * BATCH, (k + 1) * BATCH)) % len(y)
            pub.put(encode(SampleBatch("mr_damper", k, 10**12 + k * BATCH * P_NS, P_NS, None,
                                       {"velocity": u[idx]}, {"force": y[idx]})))


def _daemon(ep: str, tmp: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([*STREAMID, "daemon", "--mode", "client", "--connect", ep, "--state-dir",
                             str(tmp / "state"), "--config", str(tmp / "fast.toml"), "--stream", "mr_damper",
                             "--no-rerun", "-v"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _new_life(seen: list[ModelUpdate], old: set[object], proc: subprocess.Popen[str], n: int) -> list[ModelUpdate]:
    """Wait (bounded) until ``n`` models of an origin not in ``old`` arrived; returns them."""
    deadline = time.monotonic() + 60.0
    mine: list[ModelUpdate] = []
    while time.monotonic() < deadline and proc.poll() is None:
        mine = [u for u in list(seen) if u.origin not in old]
        if len(mine) >= n:
            break
        time.sleep(0.05)
    return mine


def test_restart_after_damaged_or_lost_state_never_silences_subscribers(tmp_path: Path) -> None:
    """SIGKILL a real daemon, damage its state file, restart: versions continue above the old ones;
    SIGKILL again, lose every file, restart: versions restart under a later epoch and are still shown."""
    (tmp_path / "fast.toml").write_text(FAST_TOML)
    ep = endpoint()
    state = tmp_path / "state" / "mr_damper.json"
    stop = threading.Event()
    seen: list[ModelUpdate] = []
    procs: list[subprocess.Popen[str]] = []
    with Bus(ZenohSettings(mode="router", listen=(ep,))) as _router, \
            ModelSubscriber(ZenohSettings(mode="client", connect=(ep,)), "mr_damper", seen.append,
                            fetch_latest=False):
        watch = subprocess.Popen([*STREAMID, "watch", "--mode", "client", "--connect", ep, "--stream", "mr_damper",
                                  "--json", "--duration", "150"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
        procs.append(watch)
        feeder = threading.Thread(target=_publish, args=(ep, stop), daemon=True)
        feeder.start()
        lives: list[list[ModelUpdate]] = []
        try:
            for life in range(3):
                proc = _daemon(ep, tmp_path)
                procs.append(proc)
                mine = _new_life(seen, {u.origin for lf in lives for u in lf}, proc, 3)
                if len(mine) < 3:
                    proc.kill()
                    raise AssertionError(f"life {life}: {len(mine)} models; daemon said:\n{proc.communicate()[1][-3000:]}")
                lives.append(mine)
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
                if life == 0:  # damage the state file: cut in the middle, garbage after (not JSON any more)
                    raw = state.read_bytes()
                    state.write_bytes(raw[: len(raw) // 2] + b"\x00\xff garbage")
                elif life == 1:  # the damaged file was quarantined; now lose every file of the state directory
                    assert len(list((tmp_path / "state").glob("mr_damper.json.corrupt-*"))) == 1
                    shutil.rmtree(tmp_path / "state")
        finally:
            stop.set()
            feeder.join(10)
            for p in procs[1:]:  # the daemons (already SIGKILLed unless an assertion stopped the loop)
                if p.poll() is None:
                    p.kill()
                    p.wait(10)
            watch.send_signal(signal.SIGINT)
            try:
                wout, werr = watch.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                watch.kill()
                wout, werr = watch.communicate()
    first, second, third = lives
    top1 = max(u.version for u in first)
    # the same daemon identity (per state directory) while the directory lived, later epochs every life
    assert first[0].origin is not None and second[0].origin is not None and third[0].origin is not None
    assert first[0].origin.daemon == second[0].origin.daemon != third[0].origin.daemon
    assert first[0].origin.epoch_ns < second[0].origin.epoch_ns < third[0].origin.epoch_ns
    # damaged state: quarantined, the version recovered from it, never reused
    assert min(u.version for u in second) > top1, ([u.version for u in first], [u.version for u in second])
    # lost state: numbering starts over, and the subscribers still take the new life's models
    assert min(u.version for u in third) == 1
    assert seen[-1].origin == third[-1].origin
    shown = [d for d in (json.loads(line) for line in wout.splitlines() if line.startswith("{"))
             if d.get("format") == "streamid.model-update/1"]  # --json prints status events too
    by_epoch = {d["origin"]["epoch_ns"] for d in shown if d.get("origin")}
    assert {first[0].origin.epoch_ns, second[0].origin.epoch_ns, third[0].origin.epoch_ns} <= by_epoch, werr[-2000:]
    assert any(d["version"] == 1 and d["origin"]["epoch_ns"] == third[0].origin.epoch_ns for d in shown)
    print("versions per life:", [[u.version for u in lf] for lf in lives], file=sys.stderr)


# --------------------------------------------------------------------------- VersionKeeper with a real identifier
SMALL = StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=5, warm_generations=2, neurons=3,
                     max_lag_y=2, max_lag_u=2, population=8, min_r2_osa=-1e9, min_r2_fr=-1e9, challenger_margin=0.0)


def _first_accepted_version(ident: OnlineIdentifier) -> int:
    """Feed 4 s of the simulated damper and return the version of the first accepted model."""
    t_ns, u, y = get_device("mr_damper").simulate_seconds(4.0, seed=1)
    ident.learn_many(t_ns, u, y, inputs=["velocity"], outputs=["force"])
    ups = [up for up in ident.update_all() if up.accepted]
    assert ups, "no accepted model"
    return ups[0].version


def _reply(payload: bytes, _key: str) -> bytes:
    return payload


def _genuine_doc(stream: str, version: int) -> bytes:
    t_ns, u, y = get_device("mr_damper").simulate_seconds(2.5, seed=2)
    ident = OnlineIdentifier(SMALL, stream=stream)
    ident.learn_many(t_ns, u, y, inputs=["velocity"], outputs=["force"])
    up = next(up for up in ident.update_all() if up.accepted)
    assert up.document is not None
    return json.dumps(dict(up.document, version=version)).encode()


def test_damaged_state_is_quarantined_and_versions_continue_above_it(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = StateStore(tmp_path)
    text = _state_text(17)
    store.path("s").write_text(text[: text.index('"signature"')] + "\x00 damaged")  # not JSON; "version":17 kept
    keeper = VersionKeeper(store, Origin("d1", 1))
    ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
    with caplog.at_level(logging.WARNING):
        assert keeper.resume(ident) is None
    assert [p.name.split(".corrupt-")[0] for p in store.quarantined("s")] == ["s.json"]
    assert "versions continue above v17" in caplog.text and "unreadable state" in caplog.text
    assert keeper.needs_settle("s")  # no usable state: the network is asked before the first model
    assert _first_accepted_version(ident) == 18
    doc = ident.document
    assert doc is not None and doc["origin"] == {"daemon": "d1", "epoch_ns": 1}


def test_no_state_asks_the_network_once_and_counts_only_the_streams_own_replies(tmp_path: Path) -> None:
    genuine = _genuine_doc("s", 41)
    others = [_genuine_doc("t", 10**6), b"not a model", json.dumps({"format": "x", "version": 10**7}).encode()]
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as server, Bus(ZenohSettings(connect=(ep,))) as client:
        server.queryable("streamid/s/model", lambda _k: genuine)
        for payload in others:  # answer on the same key: another stream's model, garbage
            server.queryable("streamid/*/model", functools.partial(_reply, payload))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(client.get("streamid/s/model", 0.5, all_replies=True)) < 4:
            time.sleep(0.05)  # declarations propagate asynchronously
        assert len(client.get("streamid/s/model", 0.5, all_replies=True)) == 4
        keeper = VersionKeeper(StateStore(tmp_path), Origin("d2", 2), query_timeout_s=1.0)
        ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
        keeper.resume(ident)
        assert keeper.settle(ident, client, threading.Lock()) == 41
        assert keeper.settle(ident, client) is None and not keeper.needs_settle("s")  # once per stream and life
        assert _first_accepted_version(ident) == 42
    # a stream with saved state does not ask
    store = StateStore(tmp_path / "b")
    store.save(StreamState("s", 5))
    keeper = VersionKeeper(store, Origin("d3", 3))
    ident = OnlineIdentifier(SMALL, stream="s")
    assert keeper.resume(ident) is not None and not keeper.needs_settle("s")
    assert keeper.settle(ident, None) is None


# --------------------------------------------------------------------------- issue 52: a forged answer to the version query
def _serve(server: Bus, client: Bus, key: str, payloads: list[bytes], want: int) -> None:
    for payload in payloads:
        server.queryable(key, functools.partial(_reply, payload))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and len(client.get(key, 0.5, all_replies=True)) < want:
        time.sleep(0.05)  # declarations propagate asynchronously
    assert len(client.get(key, 0.5, all_replies=True)) == want


def test_a_forged_version_far_above_what_the_daemon_knows_does_not_move_it(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Was: a queryable answering 2^53 - 1 made the daemon continue at 2^53, refused by every client, for its life."""
    from streamid.daemon.versions import MAX_VERSION_STEP

    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as server, Bus(ZenohSettings(connect=(ep,))) as client:
        _serve(server, client, "streamid/s/model", [_genuine_doc("s", MAX_VERSION - 1), _genuine_doc("s", 41)], 2)
        keeper = VersionKeeper(StateStore(tmp_path / "a"), Origin("d2", 2), query_timeout_s=1.0)
        ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
        keeper.resume(ident)
        with caplog.at_level(logging.WARNING, logger="streamid.daemon.versions"):
            assert keeper.settle(ident, client, threading.Lock()) == 41  # the genuine one, within the step
        assert f"answered v{MAX_VERSION - 1}, more than {MAX_VERSION_STEP}" in caplog.text and "not taken" in caplog.text
        assert _first_accepted_version(ident) == 42
        # a daemon that knows v5,000,000 (its version record) takes a step up to it + 10^6, not beyond
        store = StateStore(tmp_path / "b")
        store.record_version("s", 5_000_000)
        store.path("s").write_text("damaged")  # no usable state: the network is asked
        for v in (5_000_000 + MAX_VERSION_STEP + 1, 5_000_000 + MAX_VERSION_STEP):
            server.queryable("streamid/s/model", functools.partial(_reply, _genuine_doc("s", v)))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(client.get("streamid/s/model", 0.5, all_replies=True)) < 4:
            time.sleep(0.05)
        keeper = VersionKeeper(store, Origin("d3", 3), query_timeout_s=1.0)
        ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
        keeper.resume(ident)
        assert keeper.needs_settle("s")
        assert keeper.settle(ident, client, threading.Lock()) == 5_000_000 + MAX_VERSION_STEP
    assert _first_accepted_version(ident) == 5_000_000 + MAX_VERSION_STEP + 1


def test_the_version_query_reads_a_bounded_number_of_replies_and_bytes(tmp_path: Path) -> None:
    """2,000 replies of 256 KiB (500 MiB in all) to the daemon's version query: at most 64 read, the rest counted;
    the Python heap's peak stays far below the flood (was: every reply copied, ~500 MiB)."""
    import tracemalloc

    from streamid.daemon.versions import MAX_REPLIES, network_versions

    pad = _genuine_doc("s", 41)[:-1] + b', "pad": "' + b"x" * (256 * 1024) + b'"}'
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as server, Bus(ZenohSettings(connect=(ep,))) as client:
        server.queryable("streamid/s/model", lambda _k: [pad] * 2000)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not client.get("streamid/s/model", 0.5, all_replies=True, max_replies=1):
            time.sleep(0.05)
        tracemalloc.start()
        try:
            got = network_versions(client, "s", timeout_s=5.0)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert got.versions == (41,)
    assert got.dropped >= 1 and got.dropped + MAX_REPLIES <= 2000 and got.dropped_bytes >= got.dropped * 256 * 1024
    assert peak < 100 * 1024 * 1024, f"peak {peak / 2**20:.0f} MiB"  # 64 x 256 KiB kept, one parse at a time
    print(f"version query under a 2,000-reply flood: {got.dropped} dropped, heap peak {peak / 2**20:.1f} MiB",
          file=sys.stderr)


def test_a_version_from_the_bus_moves_the_daemons_only_within_a_bounded_step() -> None:
    """The rule the version query and a handed-over state share (streamid.daemon.versions.within_step)."""
    from streamid.daemon.versions import MAX_VERSION_STEP, within_step

    assert within_step(41, 0) and within_step(MAX_VERSION_STEP, 0) and not within_step(MAX_VERSION_STEP + 1, 0)
    assert not within_step(2**53 - 1, 40) and within_step(40 + MAX_VERSION_STEP, 40)
