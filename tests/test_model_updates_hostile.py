"""Hostile model updates over real Zenoh: clients skip, count and warn; they never raise.

Real sessions on loopback (explicit tcp/127.0.0.1 endpoints, multicast off).  A *forger*
is a plain :class:`~streamid.transport.Bus` putting crafted payloads on the model keys
(what anybody with write access to the bus can do without access control); a *daemon*
is a queryable answering with crafted documents.  Readers are the real clients:
:class:`ModelSubscriber`, :func:`latest_model` / :func:`latest_models` and a
``streamid watch`` process.  The last test runs a real :class:`Daemon` in-process.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import threading
import time
from typing import Any

import numpy as np
import pytest

from conftest import STREAMID, endpoint
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import NoModelYetError
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber, latest_model, latest_models, latest_status
from streamid.transport.updates import ModelUpdate
from streamid.wire.codec import SampleBatch, encode
from streamid.wire.documents import encode_json, model_update_message
from streamid.wire.names import unsafe_char
from streamid.wire.protobuf import len_field, varint

DEADLINE_S = 10.0


def _model(output: str, inputs: tuple[str, ...] = ("volt",)) -> Model:
    rng = np.random.default_rng(0)
    return Model(
        regressors=(Regressor("y", 0, 1), Regressor("u", 0, 1)),
        centres=rng.uniform(-1, 1, (2, 2)), widths=np.ones(2), weights=rng.normal(size=2),
        normalisation=Normalisation((-1.0,), (1.0,), -2.0, 2.0), input_names=inputs, output_name=output,
    )


def _doc(stream: str, version: int, output: str = "y", *, accepted: bool = True, code: str | None = None,
         reason: str = "", champion: int | None = None, origin: tuple[str, int] | None = None,
         inputs: tuple[str, ...] = ("volt",), fr: float = 0.95) -> dict[str, Any]:
    now = time.time_ns()
    decision = None
    if code is not None:
        decision = {"accepted": accepted, "code": code, "reason": reason, "margin": 0.01,
                    "champion": None if champion is None else {"version": champion, "r2_fr_val": 0.937,
                                                               "r2_osa_val": 0.99}}
    return model_update_message(
        stream=stream, version=version, model=_model(output, inputs).to_dict(), window={"n_samples": 100},
        metrics={"r2_osa_val": 0.99, "r2_fr_val": fr}, warm=True, generations=10, identification_s=0.1,
        window_closed_unix_ns=now, published_unix_ns=now, output=output, accepted=accepted, decision=decision,
        origin=None if origin is None else {"daemon": origin[0], "epoch_ns": origin[1]},
    )


def _payload(*args: Any, **kw: Any) -> bytes:
    return encode_json(_doc(*args, **kw))


def _overflowing(stream: str) -> bytes:
    """A valid document whose published_unix_ns is 1e400 (issue 11.4: int() raised OverflowError in clients)."""
    return _payload(stream, 9).replace(b'"published_unix_ns":', b'"published_unix_ns":1e400,"x":', 1)


def _wait(pred: Any, what: str) -> None:
    end = time.monotonic() + DEADLINE_S
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_forged_keys_and_kinds_are_skipped_counted_and_never_delivered(caplog: pytest.LogCaptureFixture) -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as forger:
        got: dict[str, list[ModelUpdate]] = {"a": [], "*": [], "b": [], "one": []}
        with ModelSubscriber(ep, "a", got["a"].append) as sub_a, \
                ModelSubscriber(ep, "*", got["*"].append) as sub_all, \
                ModelSubscriber(ep, "b", got["b"].append) as sub_b, \
                ModelSubscriber(ep, "*", got["one"].append, max_models=1) as sub_one:
            pub = forger.publisher("streamid/a/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            time.sleep(0.2)  # the other subscriptions' declarations reach the forger too
            pub.put(_payload("b", 99))  # issue 11.3: streamid/a/model carrying "stream": "b"
            pub.put(_payload("a", 98, accepted=False, code="not_better", champion=1))  # a rejected one on /model
            pub.put(_overflowing("a"))
            pub.put(_payload("a", 1))
            forger.put("streamid/e/model", _payload("e", 1))  # a second stream: beyond max_models=1
            assert sub_a.wait_for_version(1, DEADLINE_S) is not None
            assert sub_all.wait_for_version(1, DEADLINE_S, stream="e") is not None
            _wait(lambda: sub_one.errors >= 4, "the subscriber bounded to one model")
            for sub in (sub_a, sub_all, sub_one):
                want = {"malformed": 1, "key_mismatch": 1, "kind_mismatch": 1, "too_many": int(sub is sub_one)}
                assert sub.skipped == want, sub.skipped
            assert [u.version for u in got["a"]] == [1]
            assert [(u.stream, u.version) for u in got["*"]] == [("a", 1), ("e", 1)]
            assert [(u.stream, u.version) for u in got["one"]] == [("a", 1)] and list(sub_one.latest) == ["a"]
            assert got["b"] == [] and sub_b.errors == 0 and "b" not in sub_all.latest
        forger.queryable("streamid/c/model", lambda _k: _payload("b", 50))  # a daemon answering for another stream
        assert latest_model(ep, "c", timeout_s=0.5, default=None) is None  # the reply naming "b" is skipped
        with pytest.raises(NoModelYetError):
            latest_model(ep, "c", timeout_s=0.5)
    warned = [r.getMessage() for r in caplog.records if "skipped" in r.getMessage()]
    assert any("names stream 'b' but came on the key of 'a'" in m for m in warned), warned
    assert any("1e400" in m for m in warned), warned


def test_a_restarted_daemon_is_recognised_by_a_running_subscriber() -> None:
    ep = endpoint()
    old, new = ("d1", 1_000), ("d1", 2_000)
    with Bus(ZenohSettings(listen=(ep,))) as daemon:
        got: list[tuple[int, int]] = []
        with ModelSubscriber(ep, "r", lambda u: got.append((u.version, u.origin.epoch_ns))) as sub:
            pub = daemon.publisher("streamid/r/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            pub.put(_payload("r", 5, origin=old))
            pub.put(_payload("r", 6, origin=old))
            pub.put(_payload("r", 1, origin=new))  # restarted without its state: version 1 again, a later epoch
            pub.put(_payload("r", 1, origin=new))  # repeated: stale
            pub.put(_payload("r", 1, origin=("d2", 500)))  # another origin whose life began earlier: stale
            pub.put(_payload("r", 2, origin=new))
            _wait(lambda: len(got) >= 4 and sub.stale >= 2, "the restarted daemon's v2")
            assert got == [(5, 1_000), (6, 1_000), (1, 2_000), (2, 2_000)]
            assert sub.stale == 2 and sub.errors == 0
            cur = sub.current()
            assert cur is not None and cur.version == 2 and cur.origin is not None and cur.origin.epoch_ns == 2_000
        # a query answered by both lives (e.g. a stale replica): the latest life wins over the higher version
        daemon.queryable("streamid/r/model", lambda _k: _payload("r", 6, origin=old))
        daemon.queryable("streamid/r/model", lambda _k: _payload("r", 2, origin=new))
        up = latest_model(ep, "r", timeout_s=3.0)
        assert up is not None and (up.version, up.origin.epoch_ns) == (2, 2_000)


def test_accepted_only_by_default_rejected_on_request_and_one_model_per_output() -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as daemon:
        daemon.queryable("streamid/m/model", lambda _k: _payload("m", 3, "y1", code="better", champion=2))
        daemon.queryable("streamid/m/model", lambda _k: _payload("m", 4, "y2", code="first"))
        daemon.queryable("streamid/m/model", lambda _k: _payload("m", 4, "y1", accepted=False, code="not_better",
                                                                 champion=3))  # a rejected one answered on /model
        models = latest_models(ep, "m", timeout_s=3.0)
        assert {o: u.version for o, u in models.items()} == {"y1": 3, "y2": 4} and list(models) == ["y1", "y2"]
        first = latest_model(ep, "m", timeout_s=3.0)
        assert first is not None and (first.output, first.version) == ("y1", 3)
        y2 = latest_model(ep, "m", timeout_s=3.0, output="y2")
        assert y2 is not None and y2.version == 4 and y2.decision is not None and y2.decision.code == "first"
        with pytest.raises(NoModelYetError, match="no model of output 'y3' of stream 'm'.*outputs with a model: y1, y2"):
            latest_model(ep, "m", timeout_s=1.0, output="y3")

        plain: list[ModelUpdate] = []
        every: list[ModelUpdate] = []
        with ModelSubscriber(ep, "m", plain.append, latest_timeout_s=3.0) as sub, \
                ModelSubscriber(ep, "m", every.append, latest_timeout_s=3.0, include_rejected=True) as sub_rej:
            for s in (sub, sub_rej):
                assert {o: u.version for o, u in s.latest_per_output().items()} == {"y1": 3, "y2": 4}
                assert s.latest["m"].version == 4 and s.current().output == "y1"  # type: ignore[union-attr]
                assert s.skipped["kind_mismatch"] == 1
            rej = daemon.publisher("streamid/m/rejected")
            assert rej.wait_for_subscribers(DEADLINE_S)
            rej.put(_payload("m", 4, "y1", accepted=False, code="not_better", champion=3, fr=0.93))
            deadline = time.monotonic() + DEADLINE_S  # two keys, two publishers: Zenoh orders each key, not both
            while len(every) < 3 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert len(every) == 3 and len(plain) == 2  # the rejected one reached only the subscriber that asked
            pub = daemon.publisher("streamid/m/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            pub.put(_payload("m", 5, "y1", code="better", champion=3))
            assert sub.wait_for_version(5, DEADLINE_S, output="y1") is not None
            assert sub_rej.wait_for_version(5, DEADLINE_S, output="y1") is not None
            assert sub.wait_for_version(5, 0.1, output="y2") is None  # y2 is still at v4
            seen = [[(u.output, u.version, u.accepted) for u in got] for got in (plain, every)]
            for got in seen:  # the query's replies come in any order, then the puts in order
                assert sorted(got[:2]) == [("y1", 3, True), ("y2", 4, True)]
            assert seen[0][2:] == [("y1", 5, True)]
            assert seen[1][2:] == [("y1", 4, False), ("y1", 5, True)]
            assert sub_rej.rejected == 1 and sub.rejected == 0
            assert sub_rej.current(output="y1").version == 5  # type: ignore[union-attr]  # rejected never current


def test_watch_shows_each_output_with_its_decision_skips_the_malformed_and_escapes_names() -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as daemon:
        daemon.queryable("streamid/w/model", lambda _k: _payload("w", 13, "y1", code="better", champion=12))
        daemon.queryable("streamid/w/model", lambda _k: _payload("w", 12, "y2", code="first", inputs=("v\u202e",)))
        daemon.queryable("streamid/w/model", lambda _k: _overflowing("w"))
        watch = subprocess.Popen([*STREAMID, "watch", "--connect", ep, "--stream", "w", "--rejected", "--count", "2",
                                  "--duration", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            lines: list[str] = []
            reader = threading.Thread(target=lambda: lines.extend(iter(watch.stdout.readline, "")), daemon=True)
            reader.start()
            _wait(lambda: len(lines) >= 1, "the current model of y1")
            rej = daemon.publisher("streamid/w/rejected")
            assert rej.wait_for_subscribers(DEADLINE_S)
            rej.put(_payload("w", 13, "y1", accepted=False, code="validation", reason="R2 OSA 0.2 < 0.5 \u202e!"))
            assert watch.wait(timeout=30) == 0
            reader.join(timeout=5)
            err = watch.stderr.read()
        finally:
            if watch.poll() is None:
                watch.kill()
                watch.wait()
    out = "".join(lines)
    assert "Traceback" not in err and "OverflowError" not in err, err
    # an input name holding a bidi override breaks the one rule for names (streamid.wire.names): skipped, said escaped
    # (the first of the two is said, the next within the warning interval only counted)
    assert err.count("(malformed)") == 1 and "skipped 2 invalid model updates (malformed: 2)" in err, err
    assert "1e400" in err or "'inputs'[0] 'v\\u202e' holds U+202E at position 1" in err, err
    assert len(lines) == 2, out
    y1 = next(ln for ln in lines if " y1(t) " in ln and ln.startswith("w v13"))
    assert y1.rstrip().endswith("accepted: better than v12 (FR R2 0.9370 on the same data) by 0.013"), y1
    assert lines[1].startswith("w challenger rejected (serving v13) warm G=10 y1(t) = F[")
    assert lines[1].rstrip().endswith("; rejected (validation): R2 OSA 0.2 < 0.5 \\u202e!"), lines[1]
    assert unsafe_char(out.replace("\n", "")) is None and "\u202e" not in out + err


def test_a_channel_name_with_a_bidi_override_is_counted_by_the_daemon_and_never_shown() -> None:
    ep = endpoint()
    period, n = 5_000_000, 50  # 200 Hz, 50-sample batches
    _, u, y = get_device("mr_damper").simulate_seconds(6.0, seed=0)
    cfg = DaemonConfig(streams=("bidi",), discover=False, status_every_s=0.2, workers=1, helper=False,
                       retain_memory=False,
                       defaults=StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=20, warm_generations=5,
                                             neurons=4, max_lag_y=2, max_lag_u=2, min_r2_fr=-1e9))
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,))).start()
    ups: list[ModelUpdate] = []
    raw: list[bytes] = []
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, ModelSubscriber(bus, "bidi", ups.append) as sub:
            for kind in ("model", "rejected", "status"):
                bus.subscribe(f"streamid/bidi/{kind}", lambda _k, p: raw.append(p))
            pub = bus.publisher("streamid/bidi/samples", block=True)
            assert pub.wait_for_subscribers(DEADLINE_S)
            for k in range(len(u) // n):
                sl = slice(k * n, (k + 1) * n)
                if k == 20:  # a batch whose output channel is named 'f' + RIGHT-TO-LEFT OVERRIDE (hand-encoded:
                    chan = len_field(0x0A, "f\u202e".encode()) + len_field(0x12, y[sl].astype("<f8").tobytes())
                    vin = len_field(0x0A, b"v") + len_field(0x12, u[sl].astype("<f8").tobytes())
                    pub.put(b"\x08\x01" + len_field(0x12, b"bidi") + b"\x18" + varint(k) + b"\x20"  # the codec
                            + varint(k * n * period) + b"\x28" + varint(period)  # refuses to build one)
                            + len_field(0x3A, vin) + len_field(0x42, chan))
                pub.put(encode(SampleBatch("bidi", k, k * n * period, period, None, {"v": u[sl]}, {"f": y[sl]})))
                time.sleep(0.005)
            assert sub.wait_for_version(1, 30.0) is not None, "no model of the healthy channels"
            end = time.monotonic() + DEADLINE_S
            st: dict[str, Any] = {}
            while time.monotonic() < end:
                st = latest_status(bus, "bidi", timeout_s=1.0) or {}
                if st.get("bad", {}).get("decode"):
                    break
                time.sleep(0.1)
    finally:
        daemon.stop()
    assert st["bad"] == {"decode": 1}, st["bad"]
    msg = st["last_bad"]["message"]
    assert "output channel name 'f\\u202e' holds U+202E" in msg and "Cc, Cf, Zl, Zp, Co, Cs" in msg, msg
    assert st["outputs"] == ["f"] and st["inputs"] == ["v"]
    assert ups and all(up.output == "f" and up.model.input_names == ("v",) for up in ups)
    seen = b"".join(raw)  # everything the daemon published on the stream's keys: status, models
    assert "\u202e".encode() not in seen and json.dumps("\u202e").encode()[1:-1] not in seen.replace(b"\\\\", b"")


def _broken_then_good(broken: dict[str, Any], good: dict[str, Any], fmt: str) -> list[ModelUpdate]:
    """A forger on its own loopback endpoint publishes ``broken`` (version 3), then ``good`` (version 2) on stream
    ``g``'s model key; returns what a real ``ModelSubscriber`` delivered once ``good`` arrived and ``broken`` was
    counted malformed."""
    ep = endpoint()
    got: list[ModelUpdate] = []
    with Bus(ZenohSettings(listen=(ep,))) as forger, ModelSubscriber(ep, "g", got.append) as sub:
        pub = forger.publisher("streamid/g/model")
        assert pub.wait_for_subscribers(DEADLINE_S)
        pub.put(encode_json(broken))
        pub.put(encode_json(good))
        assert sub.wait_for_version(2, DEADLINE_S) is not None
        _wait(lambda: sub.skipped.get("malformed") == 1, f"the broken {fmt} document counted")
    return got


def test_a_long_linear_model_arrives_whole_and_a_broken_one_is_counted() -> None:
    """streamid.model/4 (a network with a long linear part, from an offline identification a user publishes, or a
    forger): delivered with its own linear regressors; without them it is counted malformed and never delivered."""
    lregs = (Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 0), Regressor("u", 0, 1))
    good = _doc("g", 2)
    good["model"] = dataclasses.replace(_model("y"), linear=np.array([0.5, -0.2, 0.1, 0.05, 0.0]),
                                        linear_regressors=lregs).to_dict()
    broken = json.loads(json.dumps(good))
    broken["version"] = 3
    del broken["model"]["linear_regressors"]
    got = _broken_then_good(broken, good, "/4")
    assert [u.version for u in got] == [2] and got[0].model.linear_regressors == lregs
    u = np.linspace(-1, 1, 20)
    sent = Model.from_dict(good["model"])
    np.testing.assert_allclose(got[0].model.simulate(u, np.zeros(2)), sent.simulate(u, np.zeros(2)))


def test_a_mean_with_long_linear_parts_arrives_whole_and_a_broken_one_is_counted() -> None:
    """streamid.model/5 (a mean of networks with long linear parts, as an offline identification of the F-16 saves it,
    published by a user or a forger): delivered with every member's linear regressors; a member whose ``linear``
    does not match them is counted malformed and never delivered."""
    from streamid.model import EnsembleModel

    lregs = (Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 0), Regressor("u", 0, 1))
    a = dataclasses.replace(_model("y"), linear=np.array([0.5, -0.2, 0.1, 0.05, 0.0]), linear_regressors=lregs)
    b = dataclasses.replace(a, weights=a.weights * -0.5, linear_regressors=lregs[:2], linear=np.array([0.3, 0.1, 0.0]))
    good = _doc("g", 2)
    good["model"] = EnsembleModel.of([a, b]).to_dict()
    assert good["model"]["format"] == "streamid.model/5"
    broken = json.loads(json.dumps(good))
    broken["version"] = 3
    broken["model"]["members"][1]["linear"] = [0.3, 0.1]  # two linear regressors need three numbers
    got = _broken_then_good(broken, good, "/5")
    assert [u.version for u in got] == [2] and isinstance(got[0].model, EnsembleModel)
    assert [m.linear_regressors for m in got[0].model.members] == [lregs, lregs[:2]]
    u = np.linspace(-1, 1, 20)
    np.testing.assert_allclose(got[0].model.simulate(u, np.zeros(2)), (a.simulate(u, np.zeros(2)) + b.simulate(u, np.zeros(2))) / 2)
