"""--state-dir persistence: atomic JSON documents, resume, refusal of foreign or broken files."""

from __future__ import annotations

import dataclasses
import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from streamid.online import OnlineIdentifier, RefreshPolicy, StreamConfig
from streamid.daemon.state_store import StateStore, StreamState, atomic_write_text
from streamid.online.window import Window
from streamid.online.update import identify_window
from streamid.errors import ConfigError, ModelFormatError
from streamid.sim import get_device

# short runs on 2 s windows: what these tests check is the state, not the model quality, so no FR floor
CFG = StreamConfig(window_s=2.0, update_every_s=1.0, cold_generations=30, warm_generations=10, neurons=5,
                   max_lag_y=3, max_lag_u=3, min_r2_fr=0.0)


def _window(number: int, seed: int = 0) -> Window:
    dev = get_device("mr_damper")
    t, u, y = dev.simulate_seconds(2.0, seed=seed)
    return Window("s", number, 1, int(t[0]), dev.period_ns, ("v",), ("f",), u[:, None].copy(), y[:, None].copy(),
                  0, 0)


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
        ('{"format": "streamid.daemon-state/1", "stream": "s", "version": -1}', "'version' must be an integer in \\[0, 2\\*\\*53\\)"),
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


def _samples(seconds: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dev = get_device("mr_damper")  # 200 Hz: a 2 s window is 400 samples
    return dev.simulate_seconds(seconds, seed=seed)


def test_identifier_resumes_warm_with_increasing_versions(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    t, u, y = _samples(2.0)
    ident = OnlineIdentifier(CFG, stream="s")
    ident.learn_many(t, u, y, inputs=["v"], outputs=["f"])
    up = ident.update(persist=store.save, now_ns=123)
    assert up is not None and up.accepted and up.version == 1, up and up.reason
    saved = store.load("s")
    assert saved is not None and saved.version == 1 and saved.coea_state is not None and saved.saved_unix_ns == 123
    assert up.payload is not None and json.loads(up.payload) == saved.model_message  # what was handed out was saved

    # a restarted daemon (every update a coevolution run: what is checked here is the populations' warm start; the
    # refresh schedule's resumption is tests/test_online_identifier.py's round trip and tests/test_refresh.py's)
    again = OnlineIdentifier.from_state(saved, CFG, refresh=RefreshPolicy(enabled=False))
    assert again.version == 1 and again.payload == up.payload and again.model is not None
    _, u2, y2 = _samples(2.0, seed=1)  # a new excitation, later on the same clock
    again.learn_many(t + 2_000_000_000, u2, y2, inputs=["v"], outputs=["f"])
    up2 = again.update(persist=store.save)
    assert up2 is not None and up2.outcome.warm and up2.outcome.generations == CFG.warm_generations
    assert up2.decision is not None and up2.decision.champion is not None
    assert up2.decision.champion["version"] == 1  # the restored champion was judged on the new data
    if up2.accepted:  # numbering goes on from the saved version
        assert up2.version == 2 and store.load("s").version == 2  # type: ignore[union-attr]
    else:
        assert up2.code == "not_better" and up2.version == 1 and store.load("s").version == 1  # type: ignore[union-attr]


def test_identifier_keeps_the_previous_model_when_an_update_fails(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    cfg = dataclasses.replace(CFG, update_every_s=2.0)  # windows do not overlap: the second is all flat input
    t, u, y = _samples(4.0)
    ident = OnlineIdentifier(cfg, stream="s")
    ident.learn_many(t[:400], u[:400], y[:400], inputs=["v"], outputs=["f"])
    first = ident.update(persist=store.save)
    assert first is not None and first.accepted
    payload = ident.payload
    ident.learn_many(t[400:800], np.ones(400), y[400:800], inputs=["v"], outputs=["f"])
    up = ident.update(persist=store.save)
    assert up is not None and up.kind == "dropped" and up.code == "constant_signal" and "constant" in up.reason
    assert up.event.kind == "update.dropped" and up.document is None
    assert ident.degraded and ident.version == 1 and ident.payload == payload
    assert store.load("s").version == 1  # type: ignore[union-attr]
    st = ident.status()
    assert st["degraded"] and "constant" in st["degraded_reason"]
    assert st["identifications"]["dropped"] == 1 and st["drop_reasons"] == {"constant_signal": 1}

    strict = OnlineIdentifier(dataclasses.replace(CFG, min_r2_osa=0.9999999), stream="s")
    strict.learn_many(t[:400], u[:400], y[:400], inputs=["v"], outputs=["f"])
    refused = strict.update(persist=store.save)
    assert refused is not None and refused.kind == "rejected" and "min_r2_osa" in refused.reason
    assert strict.version == 0 and strict.model is None and store.load("s").version == 1  # type: ignore[union-attr]


def test_a_model_is_still_published_when_the_state_cannot_be_saved_and_the_status_says_so() -> None:
    t, u, y = _samples(3.0)
    ident = OnlineIdentifier(CFG, stream="s")
    ident.learn_many(t, u, y, inputs=["v"], outputs=["f"])
    calls = []

    def full_disk(_state: object) -> None:
        calls.append(1)
        raise OSError(28, "No space left on device")

    ups = [u for u in ident.update_all(persist=full_disk) if u.accepted]
    assert ups and not any(u.saved for u in ups) and len(calls) == len(ups)
    assert [u.version for u in ups] == list(range(1, len(ups) + 1))  # unique, in memory
    assert ident.version == ups[-1].version and ident.payload == ups[-1].payload
    st = ident.status()
    assert st["state_saved"] is False and "No space left on device" in st["state_error"]
    assert [e.kind for e in ident.drain_events()].count("state.not_saved") == 1  # one warning, not one per update
    ident.raise_version_floor(40)  # e.g. the highest version seen on the network after the state was lost
    # a device three times stronger: the champion fails on the new data, so a challenger replaces it
    ident.learn_many(t[-1] + 5_000_000 * np.arange(1, 401), u[:400], 3 * y[:400], inputs=["v"], outputs=["f"])
    later = [u for u in ident.update_all(persist=lambda _s: None) if u.accepted]
    assert later and all(u.version > 40 and u.saved for u in later) and ident.status()["state_saved"] is True


def test_window_too_short_for_the_lags_is_dropped_with_the_reason() -> None:
    w = _window(1)
    short = Window("s", 1, 1, w.t0_ns, w.period_ns, ("v",), ("f",), w.u[:30].copy(), w.y[:30].copy(), 0, 0)
    out = identify_window(short, StreamConfig(window_samples=30, update_every_samples=10), version=1)
    assert out.kind == "dropped" and out.code == "window_too_short"
    assert "max lag 10 and 10 neurons need >= 30 estimation" in out.reason and "lengthen window_s" in out.reason
    period_s = w.period_ns / 1e9  # the concrete fix: 43 samples (30 estimation + round(0.3 x 43) = 13 validation)
    assert f"at this stream's {period_s:g} s per sample, window_s >= {43 * period_s:g} or window_samples >= 43" \
        in out.reason, out.reason
    longer = Window("s", 1, 1, w.t0_ns, w.period_ns, ("v",), ("f",), w.u[:43].copy(), w.y[:43].copy(), 0, 0)
    cfg = StreamConfig(window_samples=43, update_every_samples=10, cold_generations=5)
    assert identify_window(longer, cfg, version=1).code != "window_too_short"
    missing = identify_window(w, StreamConfig(output="torque"), version=1)
    assert missing.kind == "dropped" and "'torque' is not among the stream's outputs ['f']" in missing.reason


def test_the_shortest_window_hint_is_the_fewest_samples_the_split_accepts() -> None:
    from streamid.online.update import _shortest_window

    def fewest(need_est: int, need_val: int, f: float) -> int:
        return next(n for n in range(1, 100_000) if n - round(n * f) >= need_est and round(n * f) >= need_val)

    for need_est in (1, 5, 30, 301):
        for need_val in (1, 3, 13, 40):
            for f in (0.05, 0.1, 0.25, 0.3, 0.5, 0.7, 0.9, 0.95):
                assert _shortest_window(need_est, need_val, f) == fewest(need_est, need_val, f), (need_est, need_val, f)
