"""The daemon's evaluation helpers: one process per worker, same outcomes, gone after stop."""

from __future__ import annotations

import os
import time

import pytest

from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.online.update import identify_window
from streamid.engine import EvalHelper
from streamid.transport import ZenohSettings

from test_daemon_selection import BASE, _windows

pytestmark = pytest.mark.skipif(not EvalHelper.supported(), reason="the helper needs POSIX on x86-64")


def test_a_window_identified_with_a_helper_gives_the_same_outcome() -> None:
    wins = _windows(BASE)
    with EvalHelper() as helper:
        helper.wait_ready(30.0)  # started: a run's batches can be offered to it from the first binding on
        a = identify_window(wins[0], BASE, version=1)
        b = identify_window(wins[0], BASE, version=1, helper=helper)
        assert b.kind == "identified" and a.model.to_json() == b.model.to_json()
        assert a.summary.metrics == b.summary.metrics
        c = identify_window(wins[1], BASE, version=2, warm_state=b.state, warm_signature=b.signature, helper=helper)
        d = identify_window(wins[1], BASE, version=2, warm_state=a.state, warm_signature=a.signature)
        assert c.warm and c.model.to_json() == d.model.to_json()
        # batches were offered to it: a run binds the helper without waiting for its answer, so on a loaded machine
        # a short run may end before the helper answered; more runs (each the same model) give it the time, for up
        # to 60 s (CI's two test processes and a helper share two cores: 5 runs were not always enough)
        deadline = time.monotonic() + 60.0
        while helper.stats.offloaded + helper.stats.missed == 0 and time.monotonic() < deadline:
            e = identify_window(wins[0], BASE, version=1, helper=helper)
            assert e.model.to_json() == a.model.to_json()
        assert helper.stats.offloaded + helper.stats.missed > 0, helper.stats


@pytest.mark.parametrize("enabled", [True, False])
def test_each_worker_owns_a_helper_that_stops_with_the_daemon(zenoh_endpoint: str, enabled: bool) -> None:
    cfg = DaemonConfig(streams=("h",), workers=2, helper=enabled, defaults=StreamConfig())
    daemon = Daemon(cfg, ZenohSettings(listen=(zenoh_endpoint,))).start()
    try:
        helpers = list(daemon._helpers)
        assert len(helpers) == 2
        if not enabled:
            assert helpers == [None, None]
            return
        for h in helpers:
            h.wait_ready(30.0)
            assert h.ready and h._proc.poll() is None
        folders = [os.path.dirname(h._ctl_path) for h in helpers]
        assert all(os.path.isdir(f) for f in folders)
    finally:
        daemon.stop()
    if enabled:
        for h, f in zip(helpers, folders):
            assert h._proc.poll() is not None, "a helper outlived its daemon"
            assert not os.path.exists(f), "a helper's shared files were left behind"


def _helper_folders() -> set[str]:
    import glob
    import tempfile

    roots = ["/dev/shm", tempfile.gettempdir()]
    return {p for r in roots for p in glob.glob(os.path.join(r, "streamid-helper-*"))}


def test_a_sigkilled_daemon_leaves_no_helper_behind(tmp_path) -> None:
    """The daemon's helpers notice their owner's death, remove their shared files and exit."""
    import signal
    import time

    import numpy as np

    from conftest import endpoint
    from test_daemon_cli import replay, start_daemon, wait_version
    from test_engine_parallel import _alive

    before = _helper_folders()
    ep = endpoint()
    proc = start_daemon(tmp_path, ep)
    try:
        replay(ep, end_s=4.0)  # identifications run: the helper holds a run's data
        wait_version(ep, 1)
        mine = _helper_folders() - before
        assert mine, "the daemon started no evaluation helper"
        def pids_written() -> list[int]:
            return [int(np.fromfile(os.path.join(f, "control"), dtype=np.int64, count=2)[1]) for f in mine]

        # the helpers write their pids (control word 1) once their process has started: a helper made for a
        # later run can still be starting (seen once on a slower machine: a pid of 0 read too early)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not all(p > 0 for p in pids_written()):
            time.sleep(0.05)
        pids = pids_written()
        assert all(p > 0 for p in pids), pids
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and ((_helper_folders() & mine) or any(map(_alive, pids))):
            time.sleep(0.05)
        assert not (_helper_folders() & mine), "a helper left its shared files behind"
        assert not any(map(_alive, pids)), "a helper outlived its daemon"
    finally:
        if proc.poll() is None:
            proc.kill()
