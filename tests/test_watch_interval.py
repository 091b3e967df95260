"""``streamid watch`` shows each model's prediction interval and, when the update carries them, its coverage and
the share outside the estimation domain on held-out data; missing or hostile fields are left out, never raised on.

The formatting is checked on parsed documents (the parser a watch uses); then a real ``streamid watch`` process
reads crafted updates over real Zenoh on loopback (explicit tcp/127.0.0.1 endpoints, multicast off), and one
from a real daemon whose models carry a calibrated interval.
"""

from __future__ import annotations

import subprocess
import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np

from conftest import STREAMID, endpoint
from streamid.commands.watch import format_update, interval_part
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.model.uncertainty import LEVELS, Interval
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber
from streamid.transport.updates import ModelUpdate, parse_model_update
from streamid.wire.codec import SampleBatch, encode
from streamid.wire.documents import encode_json, model_update_message
from streamid.wire.names import unsafe_char

DEADLINE_S = 10.0
INTERVAL = Interval(LEVELS, (0.7, 1.3, 1.7, 2.1, 2.9), 0.0312, 480)


def _model(interval: Interval | None, calibration: Any) -> Model:
    rng = np.random.default_rng(0)
    return Model(regressors=(Regressor("y", 0, 1), Regressor("u", 0, 1)), centres=rng.uniform(-1, 1, (2, 2)),
                 widths=np.ones(2), weights=rng.normal(size=2), normalisation=Normalisation((-1.0,), (1.0,), -2.0, 2.0),
                 input_names=("volt",), output_name="y", interval=interval,
                 metrics={} if calibration is None else {"calibration": calibration})


def _doc(version: int, interval: Interval | None = INTERVAL, calibration: Any = None,
         **figures: float | None) -> dict[str, Any]:
    now = time.time_ns()
    return model_update_message(
        stream="iv", version=version, model=_model(interval, calibration).to_dict(), window={"n_samples": 100},
        metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.95, **figures}, warm=True, generations=10, identification_s=0.1,
        window_closed_unix_ns=now, published_unix_ns=now, output="y", accepted=True,
        decision={"accepted": True, "code": "first", "reason": "", "margin": 0.01, "champion": None})


def _parsed(doc: dict[str, Any]) -> ModelUpdate:
    return parse_model_update(encode_json(doc))


def test_the_interval_its_calibration_and_the_held_out_figures_are_on_the_update_line() -> None:
    line = format_update(_parsed(_doc(3, calibration={"r2_fr_held_out": 0.95123, "samples": 480},
                                      interval_coverage_val=0.912, outside_domain_val=0.034)))
    assert ("age " in line and "; interval 90 % FR -+ 1.7 x (0.0312 + spread), calibration held-out FR R2 0.9512; "
            "on held-out data covers 91.2 %, 3.4 % outside the estimation domain; accepted: first model") in line, line
    # without the held-out figures (a daemon that does not send them): the interval alone
    assert interval_part(_parsed(_doc(4, calibration={"r2_fr_held_out": 0.9}))) == \
        "interval 90 % FR -+ 1.7 x (0.0312 + spread), calibration held-out FR R2 0.9000"
    # a model calibrated at other levels: the one nearest 90 %
    odd = Interval((0.5, 0.95), (0.7, 2.1), 0.5, 100)
    assert interval_part(_parsed(_doc(5, interval=odd))) == "interval 95 % FR -+ 2.1 x (0.5 + spread)"
    # no interval: said, with the calibration's reason when it gives one
    assert interval_part(_parsed(_doc(6, interval=None))) == "no interval"
    assert interval_part(_parsed(_doc(7, interval=None, calibration={"reason": "too few samples to hold out (30)"}))) \
        == "no interval (too few samples to hold out (30))"


def test_missing_or_hostile_fields_are_left_out_and_never_raise() -> None:
    hostile_calibrations: list[Any] = [[1, 2], "text", 5, {"r2_fr_held_out": "0.9"}, {"r2_fr_held_out": True},
                                       {"r2_fr_held_out": 1e300}, {"r2_fr_held_out": None}, {"reason": 5},
                                       {"reason": ["a"]}, {"r2_fr_held_out": {"x": 1}}]
    for cal in hostile_calibrations:
        for interval in (INTERVAL, None):
            part = interval_part(_parsed(_doc(3, interval=interval, calibration=cal)))
            assert part in ("interval 90 % FR -+ 1.7 x (0.0312 + spread)", "no interval"), (cal, part)
    for cov, out in ((1.5, -0.1), (None, None), (-1e300, 1e300), (2, 3)):
        part = interval_part(_parsed(_doc(3, interval_coverage_val=cov, outside_domain_val=out)))
        assert part == "interval 90 % FR -+ 1.7 x (0.0312 + spread)", part
    part = interval_part(_parsed(_doc(3, interval_coverage_val=1, outside_domain_val=0)))  # integers in [0, 1]
    assert part.endswith("on held-out data covers 100.0 %, 0.0 % outside the estimation domain"), part
    # a long reason with a bidi override: cut, and escaped on the printed line
    line = format_update(_parsed(_doc(3, interval=None, calibration={"reason": "\u202e" + "x" * 500})))
    assert "no interval (\\u202e" in line and "x" * 116 + "...)" in line and "x" * 120 not in line
    assert unsafe_char(line) is None


def test_watch_prints_the_interval_of_each_update_over_real_zenoh() -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as daemon:
        daemon.queryable("streamid/iv/model", lambda _k: encode_json(_doc(
            3, calibration={"r2_fr_held_out": 0.95123}, interval_coverage_val=0.912, outside_domain_val=0.0)))
        watch = subprocess.Popen([*STREAMID, "watch", "--connect", ep, "--stream", "iv", "--count", "2",
                                  "--duration", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            lines: list[str] = []
            reader = threading.Thread(target=lambda: lines.extend(iter(watch.stdout.readline, "")), daemon=True)
            reader.start()
            end = time.monotonic() + DEADLINE_S
            while not lines:
                assert time.monotonic() < end, "timed out waiting for the current model"
                time.sleep(0.02)
            pub = daemon.publisher("streamid/iv/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            pub.put(encode_json(_doc(4, interval=None, calibration={"reason": "a refit that failed", "r2": "x"},
                                     interval_coverage_val=None, outside_domain_val=7.0)))
            assert watch.wait(timeout=30) == 0
            reader.join(timeout=5)
            err = watch.stderr.read()
        finally:
            if watch.poll() is None:
                watch.kill()
                watch.wait()
    assert "Traceback" not in err, err
    assert len(lines) == 2, lines
    assert lines[0].startswith("iv v3 ") and ("; interval 90 % FR -+ 1.7 x (0.0312 + spread), calibration held-out "
                                              "FR R2 0.9512; on held-out data covers 91.2 %, 0.0 % outside the "
                                              "estimation domain; accepted: first model") in lines[0], lines[0]
    assert lines[1].startswith("iv v4 ") and "; no interval (a refit that failed); accepted: first model" in lines[1]


def test_a_real_daemons_models_carry_their_interval_and_watch_says_so() -> None:
    """A real daemon in-process identifies a simulated damper; its models carry a calibrated interval, and the
    line a watch prints of the update the subscriber received says it (with the calibration's held-out R2)."""
    ep = endpoint()
    period, n = 5_000_000, 50
    _, u, y = get_device("mr_damper").simulate_seconds(5.0, seed=0)
    cfg = DaemonConfig(streams=("iv",), discover=False, status_every_s=0.2, workers=1, helper=False,
                       retain_memory=False,
                       defaults=StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=20, warm_generations=5,
                                             neurons=4, max_lag_y=2, max_lag_u=2, min_r2_fr=-1e9))
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,))).start()
    ups: list[ModelUpdate] = []
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, ModelSubscriber(bus, "iv", ups.append) as sub:
            pub = bus.publisher("streamid/iv/samples", block=True)
            assert pub.wait_for_subscribers(DEADLINE_S)
            for k in range(len(u) // n):
                sl = slice(k * n, (k + 1) * n)
                pub.put(encode(SampleBatch("iv", k, k * n * period, period, None, {"v": u[sl]}, {"f": y[sl]})))
                time.sleep(0.002)
            assert sub.wait_for_version(1, 30.0) is not None, "no model"
    finally:
        daemon.stop()
    up = ups[0]
    assert up.model.interval is not None and isinstance(up.model.metrics.get("calibration"), dict)
    level, q = 0.9, up.model.interval.quantile(0.9)
    line = format_update(up)
    assert f"; interval {100 * level:g} % FR -+ {q:.3g} x ({up.model.interval.scale:.4g} + spread)" in line, line
    r2 = up.model.metrics["calibration"].get("r2_fr_held_out")
    assert r2 is None or f"calibration held-out FR R2 {r2:.4f}" in line, line
    # the update line of a model that lost its interval says so (what a daemon of another version may send)
    assert "; no interval" in format_update(replace(up, model=replace(up.model, interval=None)))
