"""Resource bounds of the daemon (issue 11 items 1, 2, 5): channels, memory and time per stream, payload size,
fair scheduling across streams, and stream slots given back.

The attack test runs a real :class:`Daemon` in this process (its resident memory is this process's) and the
publishers in another (``tests/bounds_peer.py``) over real Zenoh on loopback.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import endpoint

from streamid import OnlineIdentifier, StreamConfig
from streamid.daemon.admission import Deadline, check_batch, identification_bytes
from streamid.daemon.config import DaemonConfig, config_from_mapping, to_toml
from streamid.daemon.scheduler import SHORT_JOB_S, Scheduler
from streamid.daemon.service import Daemon
from streamid.errors import ConfigError
from streamid.transport import Bus, ZenohSettings
from streamid.wire.codec import SampleBatch, encode

MiB = 1 << 20
PEER = Path(__file__).with_name("bounds_peer.py")


def vm_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS in /proc/self/status")


class RssSampler:
    """This process's resident set every 20 ms (bounded: at most 10,000 samples)."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.02) and len(self.samples) < 10_000:
            self.samples.append((time.monotonic(), vm_rss_mb()))

    def __enter__(self) -> RssSampler:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join(2.0)

    def between(self, a: float, b: float) -> list[float]:
        return [r for t, r in self.samples if a <= t < b]


# --------------------------------------------------------------------------- configuration
@pytest.mark.parametrize(("key", "value", "form"), [
    ("max_payload_bytes", 10, "an integer number of bytes in [1024, 2147483648]"),
    ("max_channels", 1, "an integer in [2, 100000]"),
    ("max_identification_bytes", 1.5e9, "an integer number of bytes in [1048576, 1099511627776]"),
    ("max_identification_s", 0.0, "a number of seconds in [0.1, 86400]"),
    ("stream_idle_s", -1.0, "a number of seconds in [0.5, 31536000]"),
])
def test_bounds_out_of_range_are_refused_naming_key_form_and_value(key: str, value: Any, form: str) -> None:
    with pytest.raises(ConfigError) as err:
        config_from_mapping({"daemon": {key: value}}, "f.toml")
    assert f"daemon.{key} must be {form}; got {value!r}" in str(err.value)


def test_bounds_are_printed_and_read_back_unchanged() -> None:
    import tomllib

    cfg = DaemonConfig(max_payload_bytes=4096, max_channels=3, max_identification_bytes=2 * MiB,
                       max_identification_s=1.5, stream_idle_s=2.0)
    text = to_toml(cfg)
    assert "max_payload_bytes = 4096\nmax_channels = 3\nmax_identification_bytes = 2097152\n" in text
    back = config_from_mapping(tomllib.loads(text))
    assert to_toml(back) == text and back.max_channels == 3 and back.max_identification_s == 1.5
    assert DaemonConfig().max_payload_bytes == 16 * MiB and DaemonConfig().stream_idle_s == 60.0


# --------------------------------------------------------------------------- admission, unit
def test_identification_bytes_is_an_upper_bound_of_the_measured_peak() -> None:
    """tracemalloc peak of one update (numpy's allocations are traced) <= the estimate <= 2x it."""
    for n, n_in in ((1500, 1), (600, 30)):
        cfg = StreamConfig(window_samples=n, update_every_samples=n, cold_generations=3, warm_generations=2)
        rng = np.random.default_rng(0)
        t = np.arange(n + 2, dtype=np.int64) * 5_000_000
        u = rng.standard_normal((n + 2, n_in))
        y = np.convolve(u.sum(1), np.ones(3) / 3, mode="same")
        ident = OnlineIdentifier(cfg, stream="s")
        ident.learn_many(t, u, y)
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            ups = ident.update_all()
            peak = tracemalloc.get_traced_memory()[1] - base
        finally:
            tracemalloc.stop()
        est = identification_bytes(n, n_in, 1, cfg)
        assert ups and peak <= est <= 2 * peak, (n, n_in, peak, est)


def _batch(n_in: int, n: int = 100, period: int = 5_000_000) -> SampleBatch:
    ins = {f"u{i}": np.zeros(n) for i in range(n_in)}
    return SampleBatch("s", 0, 0, period, None, ins, {"y": np.zeros(n)})


def test_check_batch_names_the_value_and_the_bound() -> None:
    cfg = StreamConfig(window_s=2.0)
    kind, msg = check_batch(_batch(64), cfg, max_channels=64, max_bytes=1 << 40) or ("", "")
    assert kind == "too_many_channels"
    assert "batch has 65 channels (64 inputs, 1 outputs); daemon.max_channels is 64 per stream" in msg
    assert check_batch(_batch(63), cfg, max_channels=64, max_bytes=1 << 40) is None
    need = identification_bytes(400, 30, 1, cfg)
    assert check_batch(_batch(30), cfg, max_channels=64, max_bytes=4 * need) is None
    kind, msg = check_batch(_batch(30, period=50_000), cfg, max_channels=64, max_bytes=4 * need) or ("", "")
    assert kind == "too_large_window" and "a window of 40000 samples x 30 inputs, 1 outputs" in msg
    assert "raise daemon.max_identification_bytes" in msg


def test_deadline_counts_only_its_own_time() -> None:
    stop = threading.Event()
    d = Deadline(stop, 0.05)
    assert not d.is_set()
    time.sleep(0.06)
    d.pause(0.06)  # spent on another stream's job: not this run's
    assert not d.is_set() and d.own_s < 0.05
    time.sleep(0.06)
    assert d.is_set() and d.expired
    d2 = Deadline(stop, 100.0)
    stop.set()
    assert d2.is_set() and not d2.expired


def test_scheduler_oldest_waiting_first_and_short_jobs_only_between_generations() -> None:
    s: Scheduler[str] = Scheduler()
    busy = {"a"}
    for name in ("a", "b", "c", "b"):  # b queued once
        s.wake(name)

    def take(name: str) -> str | None | bool:
        return False if name in busy else f"job-{name}"

    stop = threading.Event()
    assert s.take(take, stop, 0.0) == "job-b"  # a is busy: keeps its place, b waited longest
    s.record("c", 3.0, 10)  # 0.3 s per generation: 30 warm generations are not short
    s.record("a", 0.01, 10)
    assert s.take_short(take, lambda n: 30 * (s.sec_per_generation(n) or 1e9), exclude="x") is None
    busy.clear()
    s.wake("b")
    assert s.take_short(take, lambda n: 30 * (s.sec_per_generation(n) or 1e9), exclude="x") == "job-a"
    assert 30 * 0.001 < SHORT_JOB_S
    assert s.take(take, stop, 0.0) == "job-c"  # then the oldest again
    assert s.take(take, stop, 0.0) == "job-b"
    assert s.take(take, stop, 0.0) is None


# --------------------------------------------------------------------------- the attacks, end to end
HEALTHY = StreamConfig(window_s=2.0, update_every_s=0.5, cold_generations=60, warm_generations=10, neurons=5,
                       max_lag_y=3, max_lag_u=3)
WIDE = StreamConfig(window_s=2.0, update_every_s=1.0, cold_generations=5000, warm_generations=5000)
ATTACK = DaemonConfig(
    workers=1, helper=False, status_every_s=0.2, overrides=(("healthy", HEALTHY), ("wide", WIDE)),
    max_payload_bytes=8 * MiB, max_identification_bytes=128 * MiB, max_identification_s=2.0,
)
PLAN = {"seconds": 24.0, "wide_from_s": 9.0, "wide_to_s": 17.0, "wide_channels": 60, "payloads_at_s": 18.0,
        "payloads": [["streamid/wide/samples", 40_000_000]] * 3 + [["streamid/nobody/samples", 40_000_000],
                                                                   ["streamid/wide/samples", 100_000_000]]}


@pytest.fixture(scope="module")
def attack() -> dict[str, Any]:
    ep = endpoint()
    daemon = Daemon(ATTACK, ZenohSettings(listen=(ep,))).start()
    try:
        with RssSampler() as rss:
            t0 = time.monotonic()
            peer = subprocess.run([sys.executable, str(PEER), ep, json.dumps(PLAN)], capture_output=True, text=True,
                                  timeout=PLAN["seconds"] + 40)
            time.sleep(1.5)  # the last update; memory given back (housekeeping, at most once a second)
        assert peer.returncode == 0, peer.stderr[-2000:]
        return {"t0": t0, "rss": rss, "sent": json.loads(peer.stdout.strip().splitlines()[-1]),
                "healthy": daemon.stream_status("healthy"), "wide": daemon.stream_status("wide"),
                "updates": daemon.update_latencies("healthy"), "rss_end": vm_rss_mb()}
    finally:
        daemon.stop()


def test_attack_figures(attack: dict[str, Any]) -> None:
    t0, ups, rss = attack["t0"], attack["updates"], attack["rss"]
    ph = {"normal": (t0 + 4, t0 + PLAN["wide_from_s"]), "wide": (t0 + PLAN["wide_from_s"], t0 + PLAN["wide_to_s"]),
          "payload": (t0 + PLAN["payloads_at_s"], t0 + PLAN["seconds"])}
    for name, (a, b) in ph.items():
        lat = [s for t, _, s in ups if a <= t < b]
        r = rss.between(a, b)
        print(name, len(lat), f"lat max {max(lat):.3f} p50 {np.median(lat):.3f}" if lat else "", f"rss {min(r):.0f}..{max(r):.0f}")
    print(attack["sent"], attack["rss_end"])
    print(json.dumps(attack["wide"])[:3000])
    print(json.dumps(attack["healthy"]["daemon"]))
