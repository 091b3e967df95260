"""A stream with several outputs through a real daemon over real Zenoh (loopback): one champion per output.

The bundled CSTR log (coolant flow in; concentration and temperature out; a sample every 6 s) is
replayed at max speed onto a daemon.  Every window is identified for both outputs (stream time runs
far faster than the clock: no window is coalesced), each output gets its own champion, rejected
challengers arrive on the rejected key for a subscriber that asks, and a query on the model key
answers with one model per output.
"""

from __future__ import annotations

import subprocess
import time

import pytest
from conftest import STREAMID, endpoint

from replay.player import ReplayConfig, replay_log
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.logs import bundled_log
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber, latest_models, latest_status
from streamid.transport.updates import ModelUpdate

OUTS = ("concentration_mol_l", "temperature_K")
CFG = DaemonConfig(streams=("cstr",), defaults=StreamConfig(window_s=6000.0, update_every_s=3000.0,
                                                             cold_generations=150, warm_generations=20, seed=2))


@pytest.fixture(scope="module")
def run() -> dict[str, object]:
    ep = endpoint()
    daemon = Daemon(CFG, ZenohSettings(listen=(ep,))).start()
    got: list[ModelUpdate] = []
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, \
                ModelSubscriber(bus, "cstr", got.append, fetch_latest=False, include_rejected=True) as sub:
            replay_log(bundled_log("cstr"), bus=bus, config=ReplayConfig(max_speed=True))
            status = None
            deadline = time.monotonic() + 90
            while time.monotonic() < deadline:
                status = latest_status(bus, "cstr", timeout_s=1.0)
                if status and status["samples_in"] == 7500 and not status["busy"] and not status["windows"]["pending"]:
                    break
                time.sleep(0.2)
            time.sleep(0.3)
            models = latest_models(bus, "cstr", timeout_s=2.0)
            per_output = sub.latest_per_output("cstr")
        table = subprocess.run([*STREAMID, "status", "--connect", ep, "--timeout", "5"], capture_output=True,
                               text=True, timeout=60)
    finally:
        daemon.stop()
    return {"got": got, "status": status, "models": models, "per_output": per_output, "table": table}


def test_every_window_is_decided_for_every_output(run: dict) -> None:
    st = run["status"]
    assert st is not None and st["outputs"] == list(OUTS)
    closed = st["windows"]["closed"]
    assert closed == (7500 * 6 - 6000) // 3000 + 1 == 14 and st["windows"]["coalesced"] == 0 and not st["windows"]["live"]
    ids = st["identifications"]
    assert ids["accepted"] + ids["rejected"] == 2 * closed and ids["failed"] == ids["dropped"] == 0
    assert set(st["models"]) == set(OUTS)
    for out in OUTS:
        champ = st["models"][out]["champion"]
        assert champ is not None and champ["version"] >= 1 and champ["at_acceptance"]["r2_fr_val"] >= 0.9


def test_each_output_has_its_champion_and_rejected_challengers_arrive_when_asked(run: dict) -> None:
    got: list[ModelUpdate] = run["got"]
    accepted = [u for u in got if u.accepted]
    rejected = [u for u in got if not u.accepted]
    assert {u.output for u in accepted} == set(OUTS)
    assert [u.version for u in accepted] == sorted({u.version for u in accepted})  # one counter, never reused
    assert rejected and all(u.decision.code in ("not_better", "validation") for u in rejected)
    assert run["status"]["identifications"]["rejected"] == len(rejected)
    for u in accepted:
        assert u.model.output_name == u.output and u.decision.accepted is True
    models = run["models"]
    assert set(models) == set(OUTS)  # one reply per output to one query
    newest = {o: max((u for u in accepted if u.output == o), key=lambda u: u.version) for o in OUTS}
    assert {o: m.version for o, m in models.items()} == {o: u.version for o, u in newest.items()}
    assert {o: m.version for o, m in run["per_output"].items()} == {o: u.version for o, u in newest.items()}


def test_streamid_status_shows_a_line_per_output_under_the_stream(run: dict) -> None:
    """The real command against the daemon: the stream's line, then each output's champion on its own line."""
    table: subprocess.CompletedProcess[str] = run["table"]
    assert table.returncode == 0, table.stderr
    lines = table.stdout.splitlines()
    assert lines[0].startswith("stream ") and lines[1].split()[0] == "cstr" and lines[1].rstrip().endswith("ok")
    rows = {ln.split()[0]: ln.split() for ln in lines[2:]}
    assert set(rows) == set(OUTS) and all(ln.startswith("  ") for ln in lines[2:]), table.stdout
    for out in OUTS:  # the version each output's champion has, as the status document says
        assert rows[out][1] == f"v{run['status']['models'][out]['champion']['version']}", (out, table.stdout)
