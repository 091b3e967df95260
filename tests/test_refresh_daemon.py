"""Refreshes in a real daemon (issue 38 item 2): published documents say how a model was made, ``streamid status``
shows the next update, the status document the policy, and the daemon's log says "refreshed".

A real ``streamid daemon`` listening on tcp/127.0.0.1 (multicast scouting off), the bundled MR damper log replayed
onto it at 10x, a real subscriber of every decision (accepted and rejected).
"""

from __future__ import annotations

import json
import subprocess
import threading
from pathlib import Path
from typing import Any

from conftest import STREAMID, endpoint, stop_process, wait_until
from test_daemon_cli import replay

from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber

CONFIG = """
[defaults]
window_s = 3.0
update_every_s = 0.5
cold_generations = 60
warm_generations = 15
neurons = 6
max_lag_y = 4
max_lag_u = 4
"""


def test_a_daemon_publishes_refreshes_as_challengers_and_shows_its_policy(tmp_path: Path) -> None:
    ep = endpoint()
    cfg = tmp_path / "daemon.toml"
    cfg.write_text(CONFIG)
    log = open(tmp_path / "daemon.log", "w+", encoding="utf-8")  # noqa: SIM115 - closed below
    daemon = subprocess.Popen([*STREAMID, "daemon", "--config", str(cfg), "--listen", ep, "--no-rerun", "-v"],
                              stdout=log, stderr=subprocess.STDOUT, text=True)
    docs: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_update(up: Any) -> None:
        with lock:
            docs.append(up.document)

    try:
        assert wait_until(lambda: "serving on" in (tmp_path / "daemon.log").read_text(encoding="utf-8"), 60)
        with Bus(ZenohSettings(connect=(ep,))) as bus, \
                ModelSubscriber(bus, "mr_damper", on_update, fetch_latest=False, include_rejected=True):
            replay(ep)  # 17.5 s of log at 10x: ~30 windows of 3 s every 0.5 s
            assert wait_until(lambda: sum(d.get("update") == "refreshed" for d in list(docs)) >= 3, 60), docs[-3:]
            status = subprocess.run([*STREAMID, "status", "--connect", ep, "--timeout", "5", "--json"],
                                    capture_output=True, text=True, timeout=60)
            table = subprocess.run([*STREAMID, "status", "--connect", ep, "--timeout", "5"],
                                   capture_output=True, text=True, timeout=60)
    finally:
        stop_process(daemon)
        log.close()
    with lock:
        got = list(docs)
    # (two keys, model and rejected, two subscriptions: their documents may arrive in either order)
    first = min((d for d in got if d["accepted"]), key=lambda d: d["version"])
    assert first["version"] == 1 and first["update"] == "identified" and first["generations"] == 60
    refreshed = [d for d in got if d.get("update") == "refreshed"]
    for d in refreshed:
        # a refresh is judged like any challenger, against the champion it refreshed, and says which that was
        assert d["generations"] == 0 and d["decision"]["champion"]["version"] == d["refreshed_from"]
        assert d["model"]["metrics"]["update"] == "refreshed"
        assert d["decision"]["code"] in ("better", "not_better", "validation", "champion_invalid"), d["decision"]
        assert d["version"] == (d["refreshed_from"] + 1 if d["accepted"] else d["refreshed_from"])
    doc = json.loads(status.stdout.splitlines()[0])
    policy = doc["refresh"]["policy"]
    assert policy["enabled"] is True and policy["min_every"] >= 1 and policy["max_every"] >= policy["min_every"]
    assert doc["refresh"]["refreshed"] >= 3 and doc["refresh"]["identified"] >= 1
    assert doc["refresh"]["next"] in ("refresh", "coevolution")
    # the backlog policy (streamid.online.pending): its bound, the backlog's length in stream time and its age
    w = doc["windows"]
    assert w["max_pending_s"] == 120.0 and isinstance(w["backlog_s"], float) and w["backlog_s"] >= 0.0
    assert w["backlog_age_s"] is None or w["backlog_age_s"] >= 0.0
    assert isinstance(doc["refresh"]["deferred_backlog"], int) and not w["live"]  # a 10x replay: not live
    header, line = table.stdout.splitlines()[:2]
    column = header.index("next update")
    assert line[column:].startswith(("refresh (run in ", "coevolution")), line
    text = (tmp_path / "daemon.log").read_text(encoding="utf-8")
    if any(d["accepted"] for d in refreshed):
        assert "published (refreshed, R² validation OSA" in text, text[-2000:]
