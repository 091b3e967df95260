"""--state-dir persistence: atomic JSON documents, resume, refusal of foreign or broken files."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from streamid.daemon.config import StreamConfig
from streamid.daemon.runtime import StreamRuntime
from streamid.daemon.state_store import StateStore, StreamState, atomic_write_text
from streamid.online.window import Window
from streamid.online.update import identify_window
from streamid.errors import ConfigError, ModelFormatError
from streamid.sim import get_device

CFG = StreamConfig(window_s=2.0, update_every_s=1.0, cold_generations=30, warm_generations=10, neurons=5,
                   max_lag_y=3, max_lag_u=3)


def _window(number: int, seed: int = 0) -> Window:
    dev = get_device("mr_damper")
    t, u, y = dev.simulate_seconds(2.0, seed=seed)
    return Window("s", number, 1, int(t[0]), dev.period_ns, ("v",), ("f",), u[:, None].copy(), y[:, None].copy(),
                  0, 0, 0)


def test_round_trip_and_listing(tmp_path: Path) -> None:
    store = StateStore(tmp_path / "st")
    assert store.streams() == [] and store.load("s") is None
    st = StreamState("s", 7, {"inputs": ["v"]}, {"format": "x", "version": 7}, '{"a": 1}')
    p = store.save(st)
    assert p == tmp_path / "st" / "s.json"
    back = store.load("s")
    assert back is not None and (back.version, back.signature, back.model_message, back.coea_state) == (
        7, {"inputs": ["v"]}, {"format": "x", "version": 7}, '{"a": 1}')
    assert store.streams() == ["s"]
    assert [f.name for f in (tmp_path / "st").iterdir()] == ["s.json"]  # no temporary left behind


def test_nan_is_never_written(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    with pytest.raises(ValueError):
        store.save(StreamState("s", 1, {"x": float("nan")}))
    assert store.load("s") is None and list(tmp_path.iterdir()) == []


def test_a_failed_write_leaves_the_previous_document(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = StateStore(tmp_path)
    store.save(StreamState("s", 1))

    def boom(*_a: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        store.save(StreamState("s", 2))
    monkeypatch.undo()
    back = store.load("s")
    assert back is not None and back.version == 1
    assert [f.name for f in tmp_path.iterdir()] == ["s.json"]


def test_readers_never_see_a_partial_document(tmp_path: Path) -> None:
    path = tmp_path / "doc.json"
    atomic_write_text(path, json.dumps({"v": 0, "pad": "x"}))
    stop = threading.Event()
    seen: list[int] = []
    errors: list[str] = []

    def reader() -> None:
        while not stop.is_set():
            try:
                seen.append(json.loads(path.read_text())["v"])
            except Exception as exc:  # noqa: BLE001 - a partial read is what the test looks for
                errors.append(repr(exc))

    th = threading.Thread(target=reader)
    th.start()
    for v in range(1, 300):
        atomic_write_text(path, json.dumps({"v": v, "pad": "x" * (v * 97 % 5000)}))
    stop.set()
    th.join()
    assert errors == []
    assert seen and seen == sorted(seen)  # each read is one complete version, never older than the last


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not json", "must be JSON"),
        ('{"format": "other"}', "expected a document with format"),
        ('{"format": "streamid.daemon-state/1", "stream": "s", "version": -1}', "'version' must be an integer >= 0"),
        ('{"format": "streamid.daemon-state/1", "stream": "t", "version": 1}', "holds the state of stream 't'"),
        ('{"format": "streamid.daemon-state/1", "stream": "s", "version": 1, "coea_state": 5}', "'coea_state' a string"),
    ],
)
def test_broken_or_foreign_files_are_refused(tmp_path: Path, text: str, match: str) -> None:
    store = StateStore(tmp_path)
    (tmp_path / "s.json").write_text(text)
    with pytest.raises(ModelFormatError, match=match):
        store.load("s")
    moved = store.quarantine("s")
    assert moved is not None and moved.exists() and not (tmp_path / "s.json").exists()


def test_state_dir_must_be_creatable(tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(ConfigError, match="--state-dir"):
        StateStore(f / "sub")


def test_runtime_resumes_warm_with_increasing_versions(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    rt = StreamRuntime("s", CFG)
    w1 = _window(1)
    out = identify_window(w1, CFG, version=1)
    assert out.accepted, out.reason
    pub = rt.apply(w1, out, store)
    assert pub is not None and pub.version == 1
    saved = store.load("s")
    assert saved is not None and saved.version == 1 and saved.coea_state is not None
    assert json.loads(pub.payload) == saved.model_message  # what was published is what was saved

    again = StreamRuntime("s", CFG)  # a restarted daemon
    again.restore(saved)
    assert again.version == 1 and again.model_payload == pub.payload and again.coea_state is not None
    w2 = _window(2, seed=1)
    out2 = identify_window(w2, CFG, version=2, warm_state=again.coea_state, warm_signature=again.signature)
    assert out2.warm and out2.generations == CFG.warm_generations
    pub2 = again.apply(w2, out2, store)
    assert pub2 is not None and pub2.version == 2
    assert store.load("s").version == 2  # type: ignore[union-attr]


def test_runtime_keeps_the_previous_model_when_an_update_fails(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    rt = StreamRuntime("s", CFG)
    w1 = _window(1)
    rt.apply(w1, identify_window(w1, CFG, version=1), store)
    payload = rt.model_payload
    flat = Window("s", 2, 1, w1.t0_ns, w1.period_ns, ("v",), ("f",), np.ones((w1.n, 1)), w1.y.copy(), 0, 0, 0)
    out = identify_window(flat, CFG, version=2, warm_state=rt.coea_state, warm_signature=rt.signature)
    assert out.kind == "dropped" and out.code == "constant_signal" and "constant" in out.reason
    assert rt.apply(flat, out, store) is None
    assert rt.degraded and "constant" in rt.degraded_reason
    assert rt.version == 1 and rt.model_payload == payload and store.load("s").version == 1  # type: ignore[union-attr]
    st = rt.status()
    assert st["degraded"] and st["identifications"]["dropped"] == 1 and st["drop_reasons"] == {"constant_signal": 1}
    strict = StreamConfig(**{**CFG.to_dict(), "min_r2_osa": 0.9999999})
    out3 = identify_window(w1, strict, version=2)
    assert out3.kind == "rejected" and "min_r2_osa" in out3.reason
    assert rt.apply(w1, out3, store) is None and rt.version == 1


def test_window_too_short_for_the_lags_is_dropped_with_the_reason() -> None:
    w = _window(1)
    short = Window("s", 1, 1, w.t0_ns, w.period_ns, ("v",), ("f",), w.u[:30].copy(), w.y[:30].copy(), 0, 0, 0)
    out = identify_window(short, StreamConfig(window_samples=30, update_every_samples=10), version=1)
    assert out.kind == "dropped" and out.code == "window_too_short"
    assert "max lag 10 and 10 neurons need >= 30 estimation" in out.reason and "lengthen window_s" in out.reason
    missing = identify_window(w, StreamConfig(output="torque"), version=1)
    assert missing.kind == "dropped" and "'torque' is not among the stream's outputs ['f']" in missing.reason
