"""State files and versions under hostile or damaged input (issue 39, item 1).

Real files in a temporary directory, a real :class:`OnlineIdentifier` identifying the simulated MR
damper, the real :class:`VersionKeeper`; one real ``streamid daemon`` process for the state file
that is a symlink to ``/dev/zero``.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import time
from pathlib import Path

import pytest
from conftest import STREAMID, endpoint
from test_daemon_versions import SMALL, _first_accepted_version  # the same small stream and feed

from streamid.daemon.identity import Origin
from streamid.daemon.state_store import MAX_STATE_BYTES, RECORD_COMPACT_BYTES, StateStore
from streamid.daemon.versions import MAX_VERSION, VersionKeeper
from streamid.errors import ModelFormatError
from streamid.online import OnlineIdentifier
from streamid.online.snapshot import StreamState
from streamid.sim import get_device


def _life(store: StateStore, caplog: pytest.LogCaptureFixture) -> tuple[OnlineIdentifier, VersionKeeper]:
    keeper = VersionKeeper(store, Origin("d1", time.time_ns()))
    ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
    with caplog.at_level(logging.WARNING):
        keeper.resume(ident)
    return ident, keeper


def _persisted_lives(store: StateStore, n: int) -> int:
    """Run identifications whose states are persisted through the keeper; returns the last version saved."""
    keeper = VersionKeeper(store, Origin("d0", 1))
    ident = OnlineIdentifier(SMALL, stream="s", origin=keeper.origin_doc)
    keeper.resume(ident)
    t_ns, u, y = get_device("mr_damper").simulate_seconds(2.0 * n + 2.0, seed=4)
    ident.learn_many(t_ns, u, y, inputs=["velocity"], outputs=["force"])
    for up in ident.update_all():
        if up.accepted:
            keeper.persist(ident.state())
    return ident.version


@pytest.mark.parametrize("version", [2**63 - 1, MAX_VERSION, 10**30])
def test_a_state_beyond_the_version_bound_is_quarantined_naming_value_and_file(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, version: int) -> None:
    store = StateStore(tmp_path)
    text = StreamState("s", 3).to_json().replace('"version":3', f'"version":{version}')
    store.path("s").write_text(text)
    with pytest.raises(ModelFormatError, match=rf"'version' must be an integer in \[0, 2\*\*53\).*got {version}"):
        store.load("s")
    ident, _ = _life(store, caplog)
    assert str(version) in caplog.text and str(store.path("s")) in caplog.text
    assert not store.path("s").exists() and len(store.quarantined("s")) == 1
    assert _first_accepted_version(ident) == 1  # was: 2**63, refused by every client, the stream silenced


def test_a_handed_over_state_beyond_the_bound_and_a_bad_champion_version_are_refused() -> None:
    for doc in ({"version": 2**63 - 1}, {"version": 1, "model_message": {"version": 2**63}},
                {"version": 1, "others": {"g": {"version": 2**60}}}):
        text = json.dumps({"format": "streamid.daemon-state/1", "stream": "s", **doc})
        with pytest.raises(ModelFormatError, match=r"2\*\*53"):
            StreamState.from_json(text, source="the state handed over on streamid/@state/s")
    with pytest.raises(ValueError, match=r"2\*\*53"):
        OnlineIdentifier(SMALL, stream="s").raise_version_floor(2**63 - 1)


@pytest.mark.parametrize("damage", ["emptied", "deleted", "older"])
def test_versions_are_never_reused_after_the_state_file_is_emptied_deleted_or_replaced_by_an_older_one(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: str) -> None:
    store = StateStore(tmp_path)
    top = _persisted_lives(store, 3)
    assert top >= 2 and store.recorded_version("s") == top
    p = store.path("s")
    if damage == "emptied":
        p.write_bytes(b"")
    elif damage == "deleted":
        p.unlink()
    else:
        p.write_text(StreamState("s", 1).to_json())
    ident, _ = _life(store, caplog)
    assert f"versions continue above v{top}" in caplog.text and "s.versions" in caplog.text
    assert _first_accepted_version(ident) == top + 1  # was: 1 (emptied, deleted) or 2 (older)


def test_the_version_record_is_compacted_and_ignores_what_is_not_a_version(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    for v in range(1, 1500):
        store.record_version("s", v)
    assert store.record_path("s").stat().st_size <= RECORD_COMPACT_BYTES + 20
    assert store.recorded_version("s") == 1499
    store.record_path("s").write_bytes(b"12\n%d\nxx\n-5\n7.5\n%d\n40\n" % (MAX_VERSION, 2**63 - 1))
    assert store.recorded_version("s") == 40
    store.record_path("s").unlink()
    os.symlink("/dev/zero", store.record_path("s"))
    assert store.recorded_version("s") is None  # not a regular file: not read


@pytest.mark.parametrize("kind", ["dev-zero", "fifo", "directory", "too-large"])
def test_only_regular_state_files_under_the_size_bound_are_read(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, kind: str) -> None:
    store = StateStore(tmp_path)
    p = store.path("s")
    if kind == "dev-zero":
        os.symlink("/dev/zero", p)
    elif kind == "fifo":
        os.mkfifo(p)
    elif kind == "directory":
        p.mkdir()
    else:
        with open(p, "wb") as fh:  # sparse: costs no disk
            fh.truncate(MAX_STATE_BYTES + 1)
    rule = "more than the" if kind == "too-large" else "not a regular file"
    with pytest.raises(ModelFormatError, match=rule):
        store.load("s")
    if kind != "directory":
        ident, _ = _life(store, caplog)
        assert rule in caplog.text and str(p) in caplog.text
        assert _first_accepted_version(ident) == 1


def test_daemon_with_a_state_file_linked_to_dev_zero_starts_warns_and_stops_on_time(tmp_path: Path) -> None:
    """Was: the daemon printed nothing, ignored --duration and read /dev/zero until the OOM killer (24 GB)."""
    state = tmp_path / "state"
    state.mkdir()
    os.symlink("/dev/zero", state / "s.json")
    proc = subprocess.Popen([*STREAMID, "daemon", "--listen", endpoint(), "--state-dir", str(state), "--stream", "s",
                             "--no-rerun", "--duration", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    try:
        _, err = proc.communicate(timeout=60)  # a deadline for a stuck daemon, not a measure of speed
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError(f"the daemon did not stop: {err[-2000:]}") from None
    assert proc.returncode == 0, err[-2000:]
    assert "not a regular file" in err and "s.json" in err, err[-2000:]
    assert [q.name.split(".corrupt-")[0] for q in state.glob("s.json.corrupt-*")] == ["s.json"]


def test_a_state_holding_a_huge_champion_is_refused_before_building_it(tmp_path: Path) -> None:
    """Was: a state holding a 100,000-neuron champion took the daemon to 776 MB."""
    huge = {"format": "streamid.model/1", "inputs": ["velocity"], "output": "force",
            "regressors": [{"signal": "y", "index": 0, "lag": 1}], "centres": [[0.0]] * 100_000,
            "widths": [0.5] * 100_000, "weights": [0.1] * 100_000,
            "normalisation": {"u_low": [-1.0], "u_high": [1.0], "y_low": -1.0, "y_high": 1.0}}
    state = StreamState("s", 7, {}, {"format": "streamid.model-update/1", "stream": "s", "version": 7,
                                     "output": "force", "model": huge})
    text = state.to_json()
    got = StreamState.from_json(text, source="the state handed over on streamid/@state/s")
    ident = OnlineIdentifier(SMALL, stream="s")
    warnings = ident.restore(got)
    assert any("100000 neurons; a model has at most 1000" in w for w in warnings), warnings
    assert ident.version == 7 and ident.document is None  # the version carries over, the champion does not


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_an_identity_file_that_is_not_a_regular_file_gets_a_new_identity(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, kind: str) -> None:
    """Was: a FIFO there blocked the daemon's start for ever (a device was read to its 4 KiB bound)."""
    from streamid.daemon.identity import IDENTITY_FILE, daemon_origin

    p = tmp_path / IDENTITY_FILE
    if kind == "fifo":
        os.mkfifo(p)
    else:
        os.symlink("/dev/zero", p)
    with caplog.at_level(logging.WARNING, logger="streamid.daemon.identity"):
        o = daemon_origin(tmp_path, now_ns=7)
    assert o.epoch_ns == 7 and "not a regular file" in caplog.text


# --------------------------------------------------------------------------- issue 52, item 3: what the daemon writes
def _odd_file(p: Path, kind: str, tmp_path: Path) -> None:
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "directory":
        p.mkdir()
        (p / "inside").write_text("kept")
    elif kind == "symlink-dev-null":
        os.symlink("/dev/null", p)
    elif kind == "symlink-elsewhere":
        (tmp_path / "victim").write_text("not the daemon's\n")
        os.symlink(tmp_path / "victim", p)
    else:
        os.symlink(tmp_path / "nowhere", p)


ODD_KINDS = ["fifo", "directory", "symlink-dev-null", "symlink-elsewhere", "dangling-symlink"]


@pytest.mark.parametrize("kind", ODD_KINDS)
def test_a_version_record_that_is_not_a_regular_file_is_quarantined_and_written_fresh(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, kind: str) -> None:
    """Was: a FIFO there blocked ``record_version`` (opened without O_NONBLOCK, under the stream lock) for ever."""
    store = StateStore(tmp_path / "st")
    p = store.record_path("s")
    _odd_file(p, kind, tmp_path)
    with caplog.at_level(logging.ERROR, logger="streamid.daemon.state_store"):
        store.record_version("s", 5)  # returns (a FIFO without a reader: ENXIO at once, never a wait)
    assert not p.is_symlink() and p.is_file() and p.read_text() == "5\n" and store.recorded_version("s") == 5
    moved = list(p.parent.glob("s.versions.quarantined-*"))
    assert len(moved) == 1 and os.path.lexists(moved[0]), list(p.parent.iterdir())
    assert "not a regular file; moved aside" in caplog.text and "s.versions" in caplog.text
    assert [r.levelname for r in caplog.records] == ["ERROR"]
    if kind == "symlink-elsewhere":
        assert (tmp_path / "victim").read_text() == "not the daemon's\n"  # never written through the link
    if kind == "directory":
        assert (moved[0] / "inside").read_text() == "kept"


@pytest.mark.parametrize("kind", ODD_KINDS)
def test_a_state_document_name_that_is_not_a_regular_file_is_quarantined_before_the_rename(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, kind: str) -> None:
    store = StateStore(tmp_path / "st")
    p = store.path("s")
    _odd_file(p, kind, tmp_path)
    with caplog.at_level(logging.ERROR, logger="streamid.daemon.state_store"):
        store.save(StreamState("s", 3))  # was, for a directory: IsADirectoryError at every save, for ever
    back = store.load("s")
    assert back is not None and back.version == 3 and not p.is_symlink()
    assert len(list(p.parent.glob("s.json.quarantined-*"))) == 1 and "moved aside" in caplog.text


def test_quarantined_odd_files_are_bounded_per_name_and_directories_never_deleted(tmp_path: Path) -> None:
    from streamid.daemon.state_store import KEEP_QUARANTINED

    store = StateStore(tmp_path)
    p = store.record_path("s")
    for k in range(KEEP_QUARANTINED + 4):
        p.unlink(missing_ok=True)
        if k == 0:
            p.mkdir()
        else:
            os.mkfifo(p)
        store.record_version("s", k + 1)
    moved = sorted(tmp_path.glob("s.versions.quarantined-*"))
    assert len(moved) == KEEP_QUARANTINED + 1  # the newest 8 FIFOs and the (never deleted) directory
    assert sum(m.is_dir() for m in moved) == 1


def test_daemon_with_a_fifo_as_its_version_record_publishes_answers_and_stops(tmp_path: Path) -> None:
    """A real FIFO at STATE/<stream>.versions and a real daemon: models published, the status answered, the FIFO
    quarantined with an ERROR, SIGTERM honoured.  Was: no model ever, no status answer, SIGTERM ignored 30 s+."""
    import signal
    import stat
    import threading

    from test_daemon_versions import FAST_TOML, _daemon, _publish

    from streamid.transport import Bus, ZenohSettings
    from streamid.transport.client import ModelSubscriber, latest_status
    from streamid.transport.updates import ModelUpdate

    (tmp_path / "fast.toml").write_text(FAST_TOML)
    (tmp_path / "state").mkdir()
    fifo = tmp_path / "state" / "mr_damper.versions"
    os.mkfifo(fifo)
    ep = endpoint()
    seen: list[ModelUpdate] = []
    stop = threading.Event()
    client = ZenohSettings(mode="client", connect=(ep,))
    with Bus(ZenohSettings(mode="router", listen=(ep,))) as _router, \
            ModelSubscriber(client, "mr_damper", seen.append, fetch_latest=False):
        proc = _daemon(ep, tmp_path)
        feeder = threading.Thread(target=_publish, args=(ep, stop), daemon=True)
        feeder.start()
        try:
            deadline = time.monotonic() + 60  # a deadline for a stuck daemon, not a measure of speed
            while time.monotonic() < deadline and len(seen) < 2 and proc.poll() is None:
                time.sleep(0.05)
            status = latest_status(client, "mr_damper", timeout_s=5.0)
        finally:
            stop.set()
            feeder.join(10)
            proc.send_signal(signal.SIGTERM)
            try:
                _, err = proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                _, err = proc.communicate()
                raise AssertionError(f"SIGTERM not honoured: {err[-3000:]}") from None
    assert len(seen) >= 2, err[-3000:]
    assert status is not None and status.get("stream") == "mr_damper", err[-3000:]
    assert proc.returncode == 0, err[-3000:]
    assert "ERROR" in err and "was a FIFO, not a regular file; moved aside" in err, err[-3000:]
    moved = list((tmp_path / "state").glob("mr_damper.versions.quarantined-*"))
    assert len(moved) == 1 and stat.S_ISFIFO(os.lstat(moved[0]).st_mode)
    assert fifo.is_file() and max(int(v) for v in fifo.read_text().split()) == max(u.version for u in seen)
