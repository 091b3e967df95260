"""What a stream's status says has changed, as events (``streamid.wire.status_events``): degraded, healthy again,
and a drift (the served model no longer fits the incoming data).  The transitions on status documents, the bounds
on what a (possibly forged) status makes it remember, and end to end: a real daemon over loopback Zenoh fed the
simulated piezo whose gain changes at a known time, a ``ModelSubscriber(on_event=...)`` and the real ``streamid
watch`` CLI, which print the drift as a line and as a JSON line."""

from __future__ import annotations

import datetime
import json
import select
import subprocess
import time
from typing import Any

import numpy as np
from conftest import STREAMID, endpoint

from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.sim.drift import drift_start_ns, simulate_drift
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber, latest_status
from streamid.wire.codec import SampleBatch, encode
from streamid.wire.status_events import (
    MAX_OUTPUTS_LOOKED_AT,
    MAX_REMEMBERED,
    STATUS_EVENT_FORMAT,
    StatusChanges,
    StatusEvent,
)


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
    memory = StatusChanges()
    assert memory.update(_status(2)) == []  # two drifts before we watched: not news
    assert memory.update(_status(2)) == []
    [ev] = memory.update(_status(3, version=4))
    assert ev == StatusEvent("drift", "piezo", 4, "x", drifts=3, new=1, drift_t_ns=3_100_000_000)
    assert ev.to_dict() == {"format": STATUS_EVENT_FORMAT, "kind": "drift", "stream": "piezo", "version": 4,
                            "output": "x", "drifts": 3, "new": 1, "drift_t_ns": 3_100_000_000, "reason": ""}
    assert ev.text() == ("piezo DRIFT on x: the served model v4 no longer fits the incoming data (change "
                         "estimated at stream time 3.100 s; 3 so far); the next identification starts from the change")
    wall = datetime.datetime(2026, 11, 27, 9, 30, 0, tzinfo=datetime.timezone.utc)  # a stream on the wall clock
    [ev] = memory.update(_status(5, t_ns=int(wall.timestamp()) * 10**9 + 123_000_000))  # two at once
    assert "(change estimated at stream time 2026-11-27T09:30:00.123+00:00; 2 new, 5 so far)" in ev.text()


def test_degraded_is_said_at_once_and_healthy_again_once() -> None:
    memory = StatusChanges()
    [ev] = memory.update(_status(0, degraded=True))  # already degraded when the watch started
    assert ev.text() == "piezo DEGRADED: no model yet"
    assert memory.update(_status(0, degraded=True)) == []
    [ev] = memory.update(_status(0))
    assert ev.text() == "piezo healthy again (model v3)"
    assert StatusChanges().update(_status(0)) == []  # healthy at the first status: nothing to say


def test_what_a_forged_status_makes_it_remember_is_bounded_and_its_values_checked() -> None:
    memory = StatusChanges()
    many = {"stream": "f", "models": {f"o{i}": {"drifts": 0} for i in range(10 * MAX_OUTPUTS_LOOKED_AT)}}
    memory.update(many)
    assert len(memory) == 1 + MAX_OUTPUTS_LOOKED_AT
    for j in range(MAX_REMEMBERED):  # streams without end: the memory stops growing, nothing raises
        memory.update({"stream": f"s{j}", "degraded": False})
    assert len(memory) == MAX_REMEMBERED
    odd = {"stream": "g", "models": {"a": {"drifts": True}, "b": {"drifts": -1}, "c": {"drifts": "7"}, "d": [1],
                                     "e\u202e\x1b[2J": {"drifts": 0, "version": "v9", "drift_t_ns": 10**400}}}
    memory = StatusChanges()
    assert memory.update(odd) == [] and len(memory) == 2  # the stream, and the one output with a count
    odd["models"]["e\u202e\x1b[2J"]["drifts"] = 1  # type: ignore[index]
    [ev] = memory.update(odd)
    assert ev.version is None and ev.drift_t_ns is None
    line = ev.text()
    assert "\x1b" not in line and "\u202e" not in line and "the served model no longer fits" in line
    assert "(change time not given; 1 so far)" in line


def test_the_daemon_drift_reaches_a_subscriber_and_streamid_watch_as_a_line_and_a_json_line() -> None:
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
    seen: list[StatusEvent] = []
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, ModelSubscriber(bus, "piezo", lambda _up: None,
                                                                        on_event=seen.append) as sub:
            pub = bus.publisher("streamid/piezo/samples", block=True)
            assert pub.wait_for_subscribers(10.0)
            for w in watchers:  # their sessions are up: they say what changes from the status they hear first
                assert "waiting for models on 'piezo'" in _stderr_line(w, 30.0)
            bus.put("streamid/piezo/status", b"{not json")  # a broken and a forged status: skipped, counted
            bus.put("streamid/piezo/status", json.dumps({"format": "streamid.status/1", "stream": "other",
                                                          "degraded": True}).encode())
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
            skipped = sub.skipped
    finally:
        for w in watchers:
            w.terminate()
        outs = [w.communicate(timeout=30) for w in watchers]
        daemon.stop()
    (text, text_err), (as_json, json_err) = outs
    for err in (text_err, json_err):  # the watchers skipped them too, and say so on exit
        assert "skipped 2 invalid status messages (malformed_status: 1, status_key_mismatch: 1)" in err, err
    assert not any("DEGRADED" in ln and "other" in ln for ln in text.splitlines()), text
    drift_seen = [ev for ev in seen if ev.kind == "drift"]
    assert drift_seen and sum(ev.new for ev in drift_seen) == drifts and drift_seen[0].output == "x", seen
    assert all(ev.kind != "degraded" or ev.stream == "piezo" for ev in seen)  # the forged "other" never delivered
    assert skipped.get("malformed_status") == 1 and skipped.get("status_key_mismatch") == 1, skipped
    lines = [ln for ln in text.splitlines() if " DRIFT on x: " in ln]
    assert 1 <= len(lines) <= drifts and all("no longer fits the incoming data" in ln for ln in lines), text
    docs = [json.loads(ln) for ln in as_json.splitlines()]
    events = [d for d in docs if d.get("format") == STATUS_EVENT_FORMAT and d["kind"] == "drift"]
    assert events and sum(e["new"] for e in events) == drifts, (as_json, drifts)  # none missed, none twice
    first = events[0]
    assert first["stream"] == "piezo" and first["output"] == "x" and first["version"] >= 1
    assert abs(first["drift_t_ns"] - change_ns) <= 1_000_000_000, first  # the change, estimated within a second
    assert any(d.get("format") == "streamid.model-update/1" for d in docs)  # the models, beside the events
    assert [ev.to_dict() for ev in drift_seen] == events  # the subscriber and the CLI: the same events
    assert np.all([d.get("format") in (STATUS_EVENT_FORMAT, "streamid.model-update/1") for d in docs])
