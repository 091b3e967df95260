"""``streamid status`` shows how the champion's prediction interval did on the newest held-out data: a real daemon
(in-process, listening on tcp/127.0.0.1, multicast off) re-judges its champion on each new window and puts the
coverage and the share outside the estimation domain in its status's ``current``; a ``streamid status`` process
prints them in the stream's row (columns ``band cover`` and ``outside``)."""

from __future__ import annotations

import subprocess
import time
from typing import Any

from conftest import STREAMID, endpoint
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import latest_status
from streamid.wire.codec import SampleBatch, encode

DEADLINE_S = 60.0


def test_status_shows_the_champions_coverage_and_domain_on_current_data() -> None:
    ep = endpoint()
    period, n = 5_000_000, 50  # 200 Hz, 50-sample batches
    _, u, y = get_device("mr_damper").simulate_seconds(9.0, seed=0)
    cfg = DaemonConfig(streams=("cov",), discover=False, status_every_s=0.2, workers=1, helper=False,
                       retain_memory=False,
                       defaults=StreamConfig(window_s=2.0, update_every_s=1.0, cold_generations=20, warm_generations=5,
                                             neurons=4, max_lag_y=2, max_lag_u=2, min_r2_fr=-1e9))
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,))).start()
    current: dict[str, Any] = {}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus:
            pub = bus.publisher("streamid/cov/samples", block=True)
            assert pub.wait_for_subscribers(10.0)
            for k in range(len(u) // n):
                sl = slice(k * n, (k + 1) * n)
                pub.put(encode(SampleBatch("cov", k, k * n * period, period, None, {"v": u[sl]}, {"f": y[sl]})))
                time.sleep(0.01)
            # until every window is done and the champion's re-judged figures hold still (the table is read after)
            end, before, now = time.monotonic() + DEADLINE_S, None, None
            while time.monotonic() < end and not ("interval_coverage_val" in current and now == before):
                before = now
                time.sleep(0.5)
                st = latest_status(bus, "cov", timeout_s=1.0) or {}
                cur, w = (st.get("champion") or {}).get("current"), st.get("windows") or {}
                current = cur if isinstance(cur, dict) and w.get("pending") is False else {}
                now = (current, w.get("closed"), w.get("emitted"))
            table = subprocess.run([*STREAMID, "status", "--connect", ep, "--stream", "cov", "--timeout", "3"],
                                   capture_output=True, text=True, timeout=60)
    finally:
        daemon.stop()
    assert "interval_coverage_val" in current and "outside_domain_val" in current, current
    cov, out = current["interval_coverage_val"], current["outside_domain_val"]
    assert 0.0 <= cov <= 1.0 and 0.0 <= out <= 1.0
    assert table.returncode == 0, table.stderr
    header, line = table.stdout.splitlines()
    assert line.startswith("cov ") and line.rstrip().endswith("ok"), table.stdout
    for column, value in (("band cover", f"{100 * cov:.1f} %"), ("outside", f"{100 * out:.1f} %")):
        end = header.index(column) + len(column)  # right-aligned under its header
        assert line[end - len(value) : end] == value, (column, table.stdout)
