"""``streamid watch`` says what a stream's status says has changed: degraded, healthy again, and a drift (the
served model no longer fits the incoming data).  The transitions on status documents, the bounds on what a
(possibly forged) status makes it remember, and end to end: a real daemon over loopback Zenoh fed the simulated
piezo whose gain changes at a known time, and the real CLI printing the drift as a line and as a JSON line."""

from __future__ import annotations

import datetime
import json
import select
import subprocess
import time
from typing import Any

import numpy as np
from conftest import STREAMID, endpoint

from streamid.commands.watch import MAX_OUTPUTS_LOOKED_AT, MAX_REMEMBERED, WATCH_EVENT_FORMAT, format_event, status_events
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.sim.drift import drift_start_ns, simulate_drift
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import latest_status
from streamid.wire.codec import SampleBatch, encode


def _stderr_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """The first line ``proc`` writes on stderr within ``timeout_s`` ("" if none)."""
    assert proc.stderr is not None
    ready, _, _ = select.select([proc.stderr], [], [], timeout_s)
    return proc.stderr.readline() if ready else ""


def _status(drifts: int, *, degraded: bool = False, version: int = 3, t_ns: int | None = 3_100_000_000,
            stream: str = "piezo") -> dict[str, Any]:
    return {"stream": stream, "version": version, "degraded": degraded, "degraded_reason": "no model yet" if degraded else "",
            "models": {"x": {"version": version, "drifts": drifts, "drift_t_ns": t_ns}}}


def test_a_rising_drift_count_is_one_event_and_the_drifts_before_watching_are_history() -> None:
    memory: dict[tuple[str, str], Any] = {}
    assert status_events(memory, _status(2)) == []  # two drifts before we watched: not news
    assert status_events(memory, _status(2)) == []
    [ev] = status_events(memory, _status(3, version=4))
    assert ev == {"format": WATCH_EVENT_FORMAT, "event": "drift", "stream": "piezo", "output": "x", "version": 4,
                  "drifts": 3, "new": 1, "drift_t_ns": 3_100_000_000}
    assert format_event(ev) == ("piezo DRIFT on x: the served model v4 no longer fits the incoming data (change "
                                "estimated at stream time 3.100 s; 3 so far); the next identification starts from the change")
    wall = datetime.datetime(2026, 11, 27, 9, 30, 0, tzinfo=datetime.timezone.utc)  # a stream on the wall clock
    [ev] = status_events(memory, _status(5, t_ns=int(wall.timestamp()) * 10**9 + 123_000_000))  # two at once
    assert "(change estimated at stream time 2026-11-27T09:30:00.123+00:00; 2 new, 5 so far)" in format_event(ev)


def test_degraded_is_said_at_once_and_healthy_again_once() -> None:
    memory: dict[tuple[str, str], Any] = {}
    [ev] = status_events(memory, _status(0, degraded=True))  # already degraded when the watch started
    assert format_event(ev) == "piezo DEGRADED: no model yet"
    assert status_events(memory, _status(0, degraded=True)) == []
    [ev] = status_events(memory, _status(0))
    assert format_event(ev) == "piezo healthy again (model v3)"
    assert status_events({}, _status(0)) == []  # healthy at the first status: nothing to say


def test_what_a_forged_status_makes_it_remember_is_bounded_and_its_values_checked() -> None:
    memory: dict[tuple[str, str], Any] = {}
    many = {"stream": "f", "models": {f"o{i}": {"drifts": 0} for i in range(10 * MAX_OUTPUTS_LOOKED_AT)}}
    status_events(memory, many)
    assert len(memory) == 1 + MAX_OUTPUTS_LOOKED_AT
    for j in range(MAX_REMEMBERED):  # streams without end: the memory stops growing, nothing raises
        status_events(memory, {"stream": f"s{j}", "degraded": False})
    assert len(memory) == MAX_REMEMBERED
    odd = {"stream": "g", "models": {"a": {"drifts": True}, "b": {"drifts": -1}, "c": {"drifts": "7"}, "d": [1],
                                     "e\u202e\x1b[2J": {"drifts": 0, "version": "v9", "drift_t_ns": 10**400}}}
    memory = {}
    assert status_events(memory, odd) == [] and set(memory) == {("g", ""), ("g", "e\u202e\x1b[2J")}
    odd["models"]["e\u202e\x1b[2J"]["drifts"] = 1  # type: ignore[index]
    [ev] = status_events(memory, odd)
    assert ev["version"] is None and ev["drift_t_ns"] is None
    line = format_event(ev)
    assert "\x1b" not in line and "\u202e" not in line and "the served model no longer fits" in line
    assert "(change time not given; 1 so far)" in line


def test_the_daemon_drift_reaches_streamid_watch_as_a_line_and_a_json_line() -> None:
    """The simulated piezo's gain rises 20 % at 3 s (tests/test_drift.py: the identifier signals it within 1 s,
    with a window every 2 s).  Each 0.1 s batch waits until the daemon has decided every window closed, so the
    daemon meets the change with the champion an identifier fed the same batches would have."""
    ep = endpoint()
    cfg = DaemonConfig(defaults=StreamConfig(window_s=0.5, update_every_s=2.0), status_every_s=0.2)
    t, u, y = simulate_drift("piezo", 6.0, 3.0, 0.2, 0)
    change_ns = drift_start_ns("piezo", 3.0)
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,))).start()
    watchers = [subprocess.Popen([*STREAMID, "watch", "--connect", ep, "--stream", "piezo", "--duration", "90", *extra],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for extra in ([], ["--json"])]
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus:
            pub = bus.publisher("streamid/piezo/samples", block=True)
            assert pub.wait_for_subscribers(10.0)
            for w in watchers:  # their sessions are up: they say what changes from the status they hear first
                assert "waiting for models on 'piezo'" in _stderr_line(w, 30.0)
            for seq, k in enumerate(range(0, t.size, 2000)):
                pub.put(encode(SampleBatch("piezo", seq, int(t[k]), int(t[1] - t[0]), None, {"v": u[k : k + 2000]},
                                           {"x": y[k : k + 2000]})))
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:  # bounded: every window so far decided
                    st = latest_status(bus, "piezo", timeout_s=1.0) or {}
                    if st.get("samples_in") == min(k + 2000, t.size) and not st["busy"] and not st["windows"]["pending"]:
                        break
                    time.sleep(0.02)
                else:
                    raise AssertionError(f"the daemon did not decide the windows up to sample {k + 2000}: {st}")
            drifts = st["models"]["x"]["drifts"]
            assert drifts >= 1 and abs(st["models"]["x"]["drift_t_ns"] - change_ns) <= 1_000_000_000
            time.sleep(1.0)  # a few more statuses reach the watchers
    finally:
        for w in watchers:
            w.terminate()
        outs = [w.communicate(timeout=30)[0] for w in watchers]
        daemon.stop()
    text, as_json = outs
    lines = [ln for ln in text.splitlines() if " DRIFT on x: " in ln]
    assert 1 <= len(lines) <= drifts and all("no longer fits the incoming data" in ln for ln in lines), text
    docs = [json.loads(ln) for ln in as_json.splitlines()]
    events = [d for d in docs if d.get("format") == WATCH_EVENT_FORMAT and d["event"] == "drift"]
    assert events and sum(e["new"] for e in events) == drifts, (as_json, drifts)  # none missed, none twice
    first = events[0]
    assert first["stream"] == "piezo" and first["output"] == "x" and first["version"] >= 1
    assert abs(first["drift_t_ns"] - change_ns) <= 1_000_000_000, first  # the change, estimated within a second
    assert any(d.get("format") == "streamid.model-update/1" for d in docs)  # the models, beside the events
    assert np.all([d.get("format") in (WATCH_EVENT_FORMAT, "streamid.model-update/1") for d in docs])
