"""OnlineIdentifier: online identification as a library, with no Zenoh, no threads and no clock."""

from __future__ import annotations

import dataclasses
import json
import threading

import numpy as np
import pytest

from streamid import OnlineIdentifier, StreamConfig
from streamid.errors import DataError
from streamid.online import StreamState, Update, UpdateJob
from streamid.sim import get_device
from streamid.wire.codec import SampleBatch
from streamid.transport.updates import parse_model_update

# 200 Hz damper, 2 s windows (400 samples), one every 2 s: consecutive windows share no sample
CFG = StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=40, warm_generations=10, neurons=6,
                   max_lag_y=3, max_lag_u=3, max_pending_windows=16)
NAMES = {"inputs": ["velocity_cm_s"], "outputs": ["force_N"]}


def _model(up: Update, number: int | None = None) -> str | None:
    """The update's model as JSON (the document also holds the run's wall time, which differs run to run)."""
    if up.model is None:
        return None
    doc = up.model.to_dict()
    if number is not None:
        doc["window"]["number"] = number
    return json.dumps(doc)


@pytest.fixture(scope="module")
def damper() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, u, y = get_device("mr_damper").simulate_seconds(8.2, seed=3)
    return t[:1600], u[:1600], y[:1600]  # four whole windows


def test_samples_in_versioned_models_out(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper")
    events = ident.learn_many(t, u, y, **NAMES, now_ns=42)
    assert [e.kind for e in events] == ["window.closed"] * 4 and all(e.received_ns == 42 for e in events)
    assert ident.pending == 4 and ident.version == 0 and ident.model is None and ident.predict_one() is None
    ups = ident.update_all(now_ns=1000)
    assert [u.window.number for u in ups] == [1, 2, 3, 4] and ident.pending == 0  # every window, in order
    accepted = [u for u in ups if u.accepted]
    assert accepted and [u.version for u in accepted] == list(range(1, len(accepted) + 1))
    assert [u.outcome.warm for u in ups] == [False, True, True, True]
    last = accepted[-1]
    assert ident.version == last.version and ident.payload == last.payload and ident.model is not None
    doc = parse_model_update(last.payload)  # the document a subscriber gets
    assert doc.stream == "damper" and doc.version == last.version and doc.published_unix_ns == 1000
    assert doc.window_closed_unix_ns == 42 and last.event.kind == "update.accepted"
    assert ident.model.input_names == ("velocity_cm_s",) and ident.model.output_name == "force_N"
    st = ident.status(now_ns=7)
    assert st["version"] == last.version and st["samples_in"] == len(t) and st["unix_ns"] == 7
    assert st["identifications"]["accepted"] == len(accepted) and st["windows"]["closed"] == 4


def test_same_seed_same_models_whatever_the_batching(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    whole = OnlineIdentifier(CFG, stream="damper")
    whole.learn_many(t, u, y, **NAMES)
    a = [_model(x) for x in whole.update_all()]
    batched = OnlineIdentifier(CFG, stream="damper")
    p = int(t[1] - t[0])
    for seq, i in enumerate(range(0, len(t), 37)):  # SampleBatch in odd sizes, as a publisher would send
        batched.push(SampleBatch("damper", seq, int(t[i]), p, None, {"velocity_cm_s": u[i:i + 37]},
                                 {"force_N": y[i:i + 37]}))
    b = [_model(x) for x in batched.update_all()]
    assert len(a) == 4 and a == b and all(x is not None for x in a)


def test_learn_one_equals_learn_many(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    n = 800
    many = OnlineIdentifier(CFG, stream="damper")
    many.learn_many(t[:n], u[:n], y[:n])
    one = OnlineIdentifier(CFG, stream="damper")
    for k in range(n):  # the first sample alone cannot tell the period: it waits for the second
        one.learn_one(int(t[k]), u[k], y[k])
    assert one.pending == many.pending == 2
    assert [_model(x) for x in one.update_all()] == [_model(x) for x in many.update_all()]


def test_state_round_trip_resumes_exactly(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    half = 800  # two whole windows
    ref = OnlineIdentifier(CFG, stream="damper")
    ref.learn_many(t, u, y, **NAMES)
    ref_ups = ref.update_all()

    first = OnlineIdentifier(CFG, stream="damper")
    first.learn_many(t[:half], u[:half], y[:half], **NAMES)
    first.update_all()
    state = StreamState.from_json(first.state(now_ns=5).to_json())  # through its JSON document
    assert state.version == first.version and state.saved_unix_ns == 5
    resumed = OnlineIdentifier.from_state(state, CFG)
    assert resumed.version == first.version and resumed.payload == first.payload
    resumed.learn_many(t[half:], u[half:], y[half:], **NAMES)
    later = resumed.update_all()
    # the resumed identifier's windows hold the same samples and warm-start from the same populations;
    # only the window numbers differ (a resumed identifier counts its windows from 1)
    assert [x.window.number for x in later] == [1, 2] and [x.window.number for x in ref_ups[2:]] == [3, 4]
    assert [_model(x, number=0) for x in later] == [_model(x, number=0) for x in ref_ups[2:]]
    assert [x.version for x in later] == [x.version for x in ref_ups[2:]]
    with pytest.raises(ValueError, match="stream 'other'"):
        OnlineIdentifier(CFG, stream="other").restore(state)


def test_predict_one_and_simulate_use_the_current_model(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper")
    with pytest.raises(DataError, match="no model yet"):
        ident.simulate(u[:50], y[:10])
    ident.learn_many(t[:400], u[:400], y[:400], **NAMES)
    up = ident.update()
    assert up is not None and up.accepted
    m = ident.model
    assert m is not None
    k = 410
    ident.learn_many(t[400:k], u[400:k], y[400:k], **NAMES)
    expected = m.predict_osa(np.r_[u[:k], u[k - 1]], np.r_[y[:k], 0.0])[-1]  # y(k) from samples up to k-1
    assert ident.predict_one() == pytest.approx(expected, rel=1e-12)
    sim = ident.simulate(u[400:600], y[400:600])
    assert sim.shape == (200,) and np.allclose(sim, m.simulate(u[400:600], y[400:600]))


def test_the_caller_chooses_the_thread(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper")
    ident.learn_many(t[:800], u[:800], y[:800], **NAMES)
    job = ident.next_job()
    assert isinstance(job, UpdateJob) and job.version == 1 and ident.busy and ident.next_job() is None
    box = {}
    worker = threading.Thread(target=lambda: box.setdefault("out", job.run()))
    worker.start()
    ident.learn_many(t[800:1200], u[800:1200], y[800:1200], **NAMES)  # samples keep arriving meanwhile
    worker.join(60)
    up = ident.finish(job, box["out"])
    assert up.version == 1 and not ident.busy and ident.pending == 2
    with pytest.raises(ValueError, match="next_job"):
        ident.finish(job, box["out"])  # a job is finished once
    stop = threading.Event()
    stop.set()
    from streamid.online import Stopped

    with pytest.raises(Stopped):
        ident.update(stop=stop)
    assert not ident.busy and ident.pending == 1  # the abandoned window is gone, the next one waits


def test_bad_input_gaps_and_refusals_come_back_as_values(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper")
    ident.learn_many(t[:100], u[:100], y[:100], **NAMES)
    bad = u[100:150].copy()
    bad[3] = np.nan
    ev = ident.learn_many(t[100:150], bad, y[100:150], **NAMES)
    assert [e.kind for e in ev] == ["bad.nonfinite"] and "NaN" in ev[0].message
    ev = ident.learn_many(t[200:250], u[200:250], y[200:250], **NAMES)  # 100 samples lost on the way
    assert [e.kind for e in ev] == ["gap"] and "missing" in ev[0].message
    st = ident.status()
    assert st["bad"] == {"nonfinite": 1} and st["gaps"] == 1 and st["gap_samples"] == 100
    assert [e.kind for e in ident.drain_events()] == ["bad.nonfinite", "gap"] and ident.drain_events() == []
    flat = dataclasses.replace(CFG, min_r2_osa=1.0)  # no model reaches R^2 = 1 on a noisy window
    strict = OnlineIdentifier(flat, stream="damper")
    strict.learn_many(t[:400], u[:400], y[:400], **NAMES)
    up = strict.update()
    assert up is not None and up.kind == "rejected" and "min_r2_osa" in up.reason and strict.degraded
    assert strict.version == 0 and up.model is not None and up.document is not None
    assert up.document["accepted"] is False and up.document["decision"]["code"] == "validation" and up.decision is not None


def test_bad_arguments_name_the_value_and_the_form() -> None:
    ident = OnlineIdentifier(CFG, stream="damper")
    with pytest.raises(DataError, match=r"u must have shape \(3,\) or \(3, channels\)"):
        ident.learn_many(np.arange(3), np.zeros(4), np.zeros(3))
    with pytest.raises(DataError, match="integer nanoseconds"):
        ident.learn_many(np.array([0.5, 1.5]), np.zeros(2), np.zeros(2))
    with pytest.raises(DataError, match=r"2 u name\(s\)"):
        ident.learn_many(np.arange(3), np.zeros(3), np.zeros(3), inputs=["a", "b"])
    from streamid.errors import ConfigError

    with pytest.raises(ConfigError, match="stream name"):
        OnlineIdentifier(CFG, stream="bad name")


def test_the_readme_example_runs_and_every_window_gets_a_model() -> None:
    """examples/online_identifier.py, shown in the README: 30 s of damper in 6 s windows, a champion kept or replaced."""
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parent.parent / "examples" / "online_identifier.py"
    out = subprocess.run([sys.executable, str(example)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    rows = [ln.split() for ln in lines[:5]]
    assert rows[0][:3] == ["1", "accepted", "first"] and float(rows[0][-1]) > 0.5  # a free run that tracks the damper
    accepted = 0
    for row in rows:  # every window decided: accepted (a new version) or rejected (the champion's version stays)
        accepted += row[1] == "accepted"
        assert int(row[0]) == accepted and row[2] in ("first", "better", "champion_invalid", "not_better", "validation")
        assert row[1] == "accepted" or row[2] in ("not_better", "validation")
    assert "velocity -> force" in out.stdout and "velocity(t-" in out.stdout
    readme = (example.parent.parent / "README.md").read_text(encoding="utf-8")
    body = "\n".join(example.read_text(encoding="utf-8").splitlines()[2:])  # without the docstring
    assert body.strip() in readme, "the README's online example must be examples/online_identifier.py verbatim"


def test_direct_terms_online_when_asked_and_kept_by_warm_updates() -> None:
    rng = np.random.default_rng(7)  # 200 Hz, an output that responds within the sample: y(t) has u(t) in it
    n = 1600
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.5 * y[k - 1] + np.tanh(2 * u[k]) + 0.3 * u[k - 1]
    y += rng.normal(0, 0.02, n)
    t = np.arange(n, dtype=np.int64) * 5_000_000
    asked = OnlineIdentifier(StreamConfig(**{**CFG.to_dict(), "engine": (("direct_terms", "test"),)}), stream="d")
    asked.learn_many(t, u, y, **NAMES)
    ups = asked.update_all()
    assert [up.outcome.warm for up in ups] == [False, True, True, True]  # the state carries u(t): warm starts fit
    models = [up.outcome.model for up in ups]
    assert all(m is not None and m.config["direct_terms"] == "on" for m in models)  # tested, then kept by warm runs
    assert any(0 in m.lags["u"][0] for m in models if m is not None)
    plain = OnlineIdentifier(CFG, stream="d")  # the default online: the paper's u(t-1) on
    plain.learn_many(t, u, y, **NAMES)
    assert all(up.outcome.model is not None and up.outcome.model.config["direct_terms"] == "off" for up in plain.update_all())


def test_each_output_of_a_stream_is_healthy_or_degraded_on_its_own(
        damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """Two outputs: white noise (no model of the input predicts it: every challenger fails the floors) first,
    the damper's force second. The force's accepted models must not hide that the noise output has none: before,
    the stream's one health flag was cleared by whichever output was accepted last, and read healthy."""
    t, u, y = damper
    noise = np.random.default_rng(0).normal(0.0, 1.0, y.size)
    ident = OnlineIdentifier(CFG, stream="two")
    ident.learn_many(t, u, np.column_stack([noise, y]), inputs=["velocity_cm_s"], outputs=["noise", "force_N"])
    ups = ident.update_all()
    assert {(up.output, up.kind) for up in ups} >= {("force_N", "accepted"), ("noise", "rejected")}, \
        [(up.output, up.kind, up.code) for up in ups]
    assert all(up.code == "validation" for up in ups if up.output == "noise")
    st = ident.status()
    assert ident.degraded and st["degraded"] and st["degraded_reason"].startswith("noise: "), st["degraded_reason"]
    assert "force_N" not in st["degraded_reason"]


def test_outputs_degraded_for_the_same_reason_are_named_together(
        damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """Every output of a window too short for the lags fails alike: one reason naming both, not the reason twice
    (the CSTR replayed into a default daemon filled the 500 characters with the same sentence)."""
    t, u, y = damper
    ident = OnlineIdentifier(StreamConfig(window_samples=20, update_every_samples=20), stream="two")
    ident.learn_many(t[:40], u[:40], np.column_stack([y[:40], -y[:40]]), inputs=["v"], outputs=["a", "b"])
    ups = ident.update_all()
    assert ups and all(up.code == "window_too_short" for up in ups)
    why = ident.status()["degraded_reason"]
    assert why.startswith("a, b: window too short for the configured lags") and why.count("window too short") == 1, why


def test_a_streams_health_keeps_one_entry_per_output_it_has() -> None:
    """A publisher renaming its signals again and again must not grow what is kept of the outputs it had."""
    from streamid.online.health import Health

    health = Health()
    for k in range(1000):
        health.set(f"y{k}", "window too short", (f"y{k}",))
    assert health.current(()) == {"y999": "window too short"}  # every output ever seen, had it not been bounded
    health.set("", "stream fault", ("y999",))
    assert health.text(("y999",), one_output=False) == "stream fault; y999: window too short"
