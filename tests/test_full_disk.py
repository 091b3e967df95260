"""A full disk: the daemon keeps publishing, says so on the status, warns once, and recovers.

The state directory is a real 1 MiB tmpfs (``mount -t tmpfs``; the test is skipped,
saying why, where mounting is not permitted), filled up to the last byte before the
daemon starts.  A real :class:`Daemon` over real Zenoh on loopback identifies the
simulated MR damper; a :class:`ModelSubscriber` receives the models.

The rule (docs/reliability.md, streamid/daemon/versions.py): models are still
published when their state cannot be saved; versions stay unique (numbered in
memory; a later life has a later origin epoch); the stream's status says
``state_saved: false`` with the error; one warning per stream, not one per update;
when space comes back the next save succeeds and the status says so.
"""

from __future__ import annotations

import errno
import json
import logging
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from conftest import endpoint
from streamid.daemon.config import DaemonConfig
from streamid.daemon.identity import IDENTITY_FILE
from streamid.daemon.service import Daemon
from streamid.online import StreamConfig
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber, latest_status
from streamid.transport.updates import ModelUpdate
from streamid.wire.codec import SampleBatch, encode

P_NS = 5_000_000  # 200 Hz
BATCH = 50
CFG = StreamConfig(window_samples=400, update_every_samples=200, cold_generations=10, warm_generations=3, neurons=3,
                   max_lag_y=2, max_lag_u=2, population=8, min_r2_osa=-1e9, min_r2_fr=-1e9,
                   challenger_margin=-1.0)  # every valid challenger: the test counts published models


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[tuple[Path, Path]]:
    """(a directory on a full 1 MiB tmpfs, the filler file that takes its space)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m,mode=0700", "tmpfs", str(mnt)],
                         capture_output=True, text=True, timeout=30)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN): {res.stderr.strip()}")
    try:
        state = mnt / "state"
        state.mkdir()
        filler = mnt / "filler"
        with open(filler, "wb", buffering=0) as fh:
            chunk = b"\0" * 4096
            for _ in range(1024):  # 4 MiB at most on a 1 MiB disk: bounded
                try:
                    fh.write(chunk)
                except OSError as exc:
                    assert exc.errno == errno.ENOSPC
                    break
            else:
                pytest.fail("the 1 MiB tmpfs never filled up")
        with pytest.raises(OSError) as info:  # really full now
            (state / "probe").write_bytes(b"x" * 4096)
        assert info.value.errno == errno.ENOSPC
        (state / "probe").unlink(missing_ok=True)
        yield state, filler
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True, timeout=30)


def _publish(ep: str, stop: threading.Event) -> None:
    _, u, y = get_device("mr_damper").simulate_seconds(30.0, seed=4)
    with Bus(ZenohSettings(connect=(ep,))) as bus:
        pub = bus.publisher("streamid/disk/samples", block=True)
        assert pub.wait_for_subscribers(20.0)
        for k in range(20_000):  # bounded: 20,000 batches at most
            if stop.wait(BATCH * P_NS / 1e9 / 4):  # 4x real time
                return
            idx = np.arange(k * BATCH, (k + 1) * BATCH) % len(y)
            pub.put(encode(SampleBatch("disk", k, 10**12 + k * BATCH * P_NS, P_NS, None,
                                       {"velocity": u[idx]}, {"force": y[idx]})))


def _wait(pred: object, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():  # type: ignore[operator]
            return True
        time.sleep(0.05)
    return False


def test_full_disk_keeps_publishing_warns_once_and_recovers(
        full_disk: tuple[Path, Path], caplog: pytest.LogCaptureFixture) -> None:
    state_dir, filler = full_disk
    ep = endpoint()
    seen: list[ModelUpdate] = []
    stop = threading.Event()
    caplog.set_level(logging.WARNING)
    daemon = Daemon(DaemonConfig(defaults=CFG, status_every_s=0.2, streams=("disk",)), ZenohSettings(listen=(ep,)),
                    state_dir=state_dir).start()
    feeder = threading.Thread(target=_publish, args=(ep, stop), daemon=True)
    try:
        with Bus(ZenohSettings(connect=(ep,))) as watcher, ModelSubscriber(watcher, "disk", seen.append):
            feeder.start()
            assert _wait(lambda: len(seen) >= 4, 60.0), f"{len(seen)} models published on a full disk"
            full_status = latest_status(watcher, "disk", timeout_s=2.0)
            n_full = len(seen)
            assert not (state_dir / "disk.json").exists()  # nothing could be saved ...
            filler.unlink()  # ... until space comes back
            assert _wait(lambda: (state_dir / "disk.json").exists() and len(seen) > n_full + 1, 60.0)
            assert _wait(lambda: (latest_status(watcher, "disk", timeout_s=1.0) or {}).get("state_saved") is True,
                         10.0)
    finally:
        stop.set()
        feeder.join(10)
        daemon.stop()
    versions = [u.version for u in seen]
    assert versions == list(range(versions[0], versions[0] + len(versions)))  # unique, increasing, no hole
    assert {u.origin for u in seen} == {seen[0].origin} and seen[0].origin is not None
    assert full_status is not None and full_status["state_saved"] is False
    assert "No space left on device" in full_status["state_error"], full_status["state_error"]
    not_saved = [r for r in caplog.records if "state not saved" in r.getMessage() and "disk" in r.getMessage()]
    assert len(not_saved) == 1, [r.getMessage() for r in not_saved]  # one warning for >= 4 updates
    assert "No space left on device" in not_saved[0].getMessage()
    print(f"versions {versions} ({n_full} while full); status: {full_status['state_error']!r}", file=sys.stderr)
    assert any("state saved again" in r.getMessage() for r in caplog.records)
    assert any("daemon identity not saved" in r.getMessage() for r in caplog.records)  # it was full at start
    saved = json.loads((state_dir / "disk.json").read_text())
    assert saved["version"] == versions[-1]  # the latest state is on disk again
    # the identity could not be written at start; it was once a state save succeeded again
    assert json.loads((state_dir / IDENTITY_FILE).read_text())["daemon"] == seen[0].origin.daemon
