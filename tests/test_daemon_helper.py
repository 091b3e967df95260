"""The daemon's evaluation helpers: one process per worker, same outcomes, gone after stop."""

from __future__ import annotations

import os

import pytest

from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.daemon.worker import identify_window
from streamid.engine import EvalHelper
from streamid.transport import ZenohSettings

from test_daemon_selection import BASE, _windows

pytestmark = pytest.mark.skipif(not EvalHelper.supported(), reason="the helper needs POSIX on x86-64")


def test_a_window_identified_with_a_helper_gives_the_same_outcome() -> None:
    wins = _windows(BASE)
    with EvalHelper() as helper:
        a = identify_window(wins[0], BASE, version=1)
        b = identify_window(wins[0], BASE, version=1, helper=helper)
        assert b.accepted and a.model.to_json() == b.model.to_json()
        assert a.summary.metrics == b.summary.metrics
        c = identify_window(wins[1], BASE, version=2, warm_state=b.state, warm_signature=b.signature, helper=helper)
        d = identify_window(wins[1], BASE, version=2, warm_state=a.state, warm_signature=a.signature)
        assert c.warm and c.model.to_json() == d.model.to_json()
        assert helper.stats.offloaded + helper.stats.missed > 0  # batches were offered to it


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
