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
    from streamid.engine.warmup import warm_up_kernels

    warm_up_kernels()  # the compiled kernels loaded first, as the daemon does at start: a one-time load is not an update's
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
    now = [100.0]  # a clock of the test's own: the rule, not this machine's speed
    d = Deadline(stop, 0.05, clock=lambda: now[0])
    assert not d.is_set()
    now[0] += 0.06
    d.pause(0.06)  # spent on another stream's job: not this run's
    assert not d.is_set() and d.own_s == pytest.approx(0.0)
    now[0] += 0.06
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


def test_scheduler_takes_a_streams_first_run_before_the_served_streams_jobs() -> None:
    s: Scheduler[str] = Scheduler()
    for name in ("a", "new1", "b", "new2", "c"):
        s.wake(name)
    first = {"new1", "new2"}
    busy = {"new2"}

    def take(name: str) -> str | None | bool:
        return False if name in busy else f"job-{name}"

    stop = threading.Event()
    assert s.any_waiting(lambda n: n in first) and not s.any_waiting(lambda n: n == "x")
    assert s.take(take, stop, 0.0, first=lambda n: n in first) == "job-new1"
    assert s.take(take, stop, 0.0, first=lambda n: n in first) == "job-a"  # new2 busy: keeps its place
    busy.clear()
    assert [s.take(take, stop, 0.0, first=lambda n: n in first) for _ in range(3)] == ["job-new2", "job-b", "job-c"]
    assert s.take(take, stop, 0.0, first=lambda n: n in first) is None


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


def _attack_here(ep: str) -> dict[str, Any]:
    """The attack on a daemon in this process (run in a fresh process: its memory is the daemon's alone)."""
    daemon = Daemon(ATTACK, ZenohSettings(listen=(ep,))).start()
    try:
        with RssSampler() as rss:
            t0 = time.monotonic()
            peer = subprocess.run([sys.executable, str(PEER), ep, json.dumps(PLAN)], capture_output=True, text=True,
                                  timeout=PLAN["seconds"] + 40)
            time.sleep(1.5)  # the last update; memory given back (housekeeping, at most once a second)
        assert peer.returncode == 0, peer.stderr[-2000:]
        return {"t0": t0, "rss": rss.samples, "sent": json.loads(peer.stdout.strip().splitlines()[-1]),
                "healthy": daemon.stream_status("healthy"), "wide": daemon.stream_status("wide"),
                "updates": daemon.update_latencies("healthy"), "rss_end": vm_rss_mb()}
    finally:
        daemon.stop()


@pytest.fixture(scope="module")
def attack() -> dict[str, Any]:
    """The attack, on a daemon in a fresh process (as deployed: the test process's own heap would blur its RSS)."""
    out = subprocess.run([sys.executable, __file__, endpoint()], capture_output=True, text=True,
                         timeout=PLAN["seconds"] + 90)
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    sampler = RssSampler()
    sampler.samples = [(float(t), float(r)) for t, r in res["rss"]]
    res["rss"] = sampler
    res["updates"] = [tuple(u) for u in res["updates"]]
    return res


def _phases(attack: dict[str, Any]) -> dict[str, tuple[float, float]]:
    t0 = attack["t0"]
    return {"normal": (t0 + 4.0, t0 + PLAN["wide_from_s"]), "wide": (t0 + PLAN["wide_from_s"], t0 + PLAN["wide_to_s"]),
            "payloads": (t0 + PLAN["payloads_at_s"], t0 + PLAN["seconds"])}


def test_healthy_stream_keeps_its_latency_while_another_stream_sends_wide_batches(attack: dict[str, Any]) -> None:
    ups, figures, gaps = attack["updates"], {}, {}
    for name, (a, b) in _phases(attack).items():
        lat = [s for t, _, s in ups if a <= t < b]
        times = [t for t, _, _ in ups if a <= t < b]
        assert len(lat) >= 0.7 * (b - a) / HEALTHY.update_every_s, (name, len(lat))  # an update every 0.5 s
        gaps[name] = float(max(np.diff(times)))
        figures[name] = (float(np.median(lat)), max(lat))
    # No stall: under attack the longest gap between the healthy stream's updates is at most its own longest gap
    # of the normal phase and two update periods (relative to this run, not a wall-clock time of the machine:
    # issue 39 item 5).
    for name in ("wide", "payloads"):
        assert gaps[name] <= gaps["normal"] + 2 * HEALTHY.update_every_s, gaps
    normal_max = figures["normal"][1]
    for name in ("wide", "payloads"):
        # waiting at most one generation of the long run, or its start (measured 0.26 s at 600 candidates)
        assert figures[name][1] <= normal_max + 0.5, figures
        assert figures[name][0] <= 2 * figures["normal"][0] + 0.02, figures
    assert attack["healthy"]["nested_runs"] >= 1  # its updates went between the wide run's generations
    print("healthy latency p50/max per phase:", {k: f"{a:.3f}/{b:.3f} s" for k, (a, b) in figures.items()})


def test_wide_batches_are_refused_or_stopped_and_counted(attack: dict[str, Any]) -> None:
    wide = attack["wide"]
    assert attack["sent"]["wide_refused"] == wide["bad"]["too_many_channels"] == 10  # 2,000 channels each
    # 60 channels are within the bound; their identifications (5,000 generations) are stopped at 2 s each
    assert wide["identification_timeouts"] >= 2 and wide["identifications"]["failed"] >= 2
    assert wide["version"] == 0 and "longer than daemon.max_identification_s = 2 s" in wide["degraded_reason"]
    assert attack["healthy"]["daemon"]["identification_timeouts"] == wide["identification_timeouts"]


def test_large_payloads_are_refused_before_decoding_and_memory_is_given_back(attack: dict[str, Any]) -> None:
    wide, info, rss = attack["wide"], attack["healthy"]["daemon"], attack["rss"]
    assert wide["bad"]["too_large"] == 3  # 40 MB on the wide stream's key: refused undecoded, counted there
    assert "payload of 40000000 bytes" in wide["last_bad"]["message"]
    assert info["payloads_too_large"] == 1  # 40 MB on a key of no stream: on the daemon's counters
    # (the 100 MB payload is beyond Zenoh's own bound, 8 x max_payload_bytes: dropped by Zenoh, never seen)
    ph = _phases(attack)
    base = float(np.median(rss.between(*ph["normal"])))
    peak = max(r for _, r in rss.samples)
    bound = base + (ATTACK.max_identification_bytes + 8 * ATTACK.max_payload_bytes) / MiB
    assert peak <= bound, (base, peak, bound)
    assert attack["rss_end"] <= base + 32, (base, attack["rss_end"])  # given back
    print(f"daemon RSS before {base:.0f} MB, peak {peak:.0f} MB (bound {bound:.0f}), after {attack['rss_end']:.0f} MB")


def _damper_batches(stream: str, n: int, b: int = 50, k0: int = 0) -> list[bytes]:
    from streamid.sim import get_device

    dev = get_device("mr_damper")
    _, u, y = dev.simulate_seconds((k0 + n) * b * dev.period_ns / 1e9 + 0.1, seed=5)
    p = dev.period_ns
    return [encode(SampleBatch(stream, k, k * b * p, p, None, {"v": u[k * b:(k + 1) * b]}, {"f": y[k * b:(k + 1) * b]}))
            for k in range(k0, k0 + n)]


def _until(cond: Any, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return bool(cond())


def test_junk_stream_names_give_their_slots_back_and_a_real_stream_gets_one(tmp_path: Path) -> None:
    """20,000 junk names against max_streams = 8: a real stream starting later is served; silent streams are released."""
    cfg = DaemonConfig(max_streams=8, stream_idle_s=1.5, status_every_s=0.2, workers=1, helper=False,
                       defaults=StreamConfig(window_s=1.0, update_every_s=1.0, cold_generations=20, neurons=4,
                                             max_lag_y=2, max_lag_u=2, min_r2_osa=-1e9, min_r2_fr=-1e9))
    ep = endpoint()
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,)), state_dir=tmp_path / "state").start()
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus:
            assert bus.wait_connected(10.0)
            early = bus.publisher("streamid/early/samples")
            assert early.wait_for_subscribers(10.0)
            for p in _damper_batches("early", 10):  # 2.5 s of a real stream: a model, saved
                early.put(p)
            assert _until(lambda: (daemon.stream_status("early") or {}).get("version", 0) >= 1, 20.0)
            version = daemon.stream_status("early")["version"]  # type: ignore[index]
            t_flood = time.monotonic()
            for i in range(20_000):  # junk payloads on 20,000 names, as fast as Zenoh takes them
                bus.put(f"streamid/junk{i}/samples", b"\x00junk")
            assert _until(lambda: daemon._global["streams_refused"] > 0, 10.0)  # noqa: SLF001
            flood_s = time.monotonic() - t_flood
            late = bus.publisher("streamid/late/samples")
            refused_at_start = daemon._global["streams_refused"]  # noqa: SLF001
            for p in _damper_batches("late", 24):  # a real stream, in real time: 0.25 s per batch
                late.put(p)
                time.sleep(0.25)
            assert _until(lambda: (daemon.stream_status("late") or {}).get("version", 0) >= 1, 20.0)
            late_samples = daemon.stream_status("late")["samples_in"]  # type: ignore[index]
            # "early" gave its slot back after stream_idle_s without a valid sample; its state file stays
            assert _until(lambda: daemon.stream_status("early") is None, 5.0)
            assert (tmp_path / "state").exists() and any("early" in p.name for p in (tmp_path / "state").rglob("*"))
            info = daemon.stream_status("late")["daemon"]  # type: ignore[index]
            assert info["streams"] <= cfg.max_streams
            assert info["streams_released"] >= cfg.max_streams  # every junk slot, and "early"
            assert info["streams_refused"] >= refused_at_start > 0
            assert late_samples >= 12 * 50  # served within the first half of its batches
            early.put(_damper_batches("early", 1, k0=10)[0])  # it comes back: resumed from its state file
            assert _until(lambda: (daemon.stream_status("early") or {}).get("version", 0) >= version, 5.0)
            print(f"flood of 20,000 names: {flood_s:.2f} s; late samples in {late_samples} of 1200; counters {info}")
    finally:
        daemon.stop()


if __name__ == "__main__":  # the attack fixture's daemon process
    from streamid.commands.main import leave

    print(json.dumps(_attack_here(sys.argv[1])))
    leave(0)  # as the streamid command leaves: no interpreter finalisation racing a Zenoh thread (a CI abort, -6)


FAKE_RUNS: list[_FakeJob] = []


class _FakeJob:
    """A job of ``generations`` generations of ``gen_s`` seconds each (sleeps), through the runner's hooks."""

    def __init__(self, name: str, generations: int, gen_s: float) -> None:
        from types import SimpleNamespace

        self.name, self.generations, self.gen_s = name, generations, gen_s
        self.window = SimpleNamespace(n=100, input_names=("u",), output_names=("y",))

    def run(self, *, stop: Any, on_generation: Any, helper: Any) -> Any:
        from streamid.online import Outcome

        t0 = time.monotonic()
        for _ in range(self.generations):
            time.sleep(self.gen_s)
            if stop.is_set():
                raise AssertionError("stopped")
            on_generation(self.name, None)
        self.took_s, self.own_s, self.paused_s = time.monotonic() - t0, stop.own_s, stop.paused_s
        FAKE_RUNS.append(self)
        return Outcome("dropped", "fake", "fake")


class _FakeIdent:
    """The part of an OnlineIdentifier the runner uses: ``jobs`` more jobs due, one out at a time."""

    def __init__(self, name: str, jobs: int, generations: int, gen_s: float) -> None:
        from streamid.online.stream_config import StreamConfig

        self.stream, self.config, self.version = name, StreamConfig(), 1
        self.left, self.generations, self.gen_s = jobs, generations, gen_s
        self.out: Any = None
        self.taken = 0

    @property
    def first_run_due(self) -> bool:
        return self.taken == 0 and self.left > 0

    @property
    def busy(self) -> bool:
        return self.out is not None

    @property
    def pending(self) -> int:
        return self.left

    def next_job(self, defer_scheduled: bool = False, first_generations: int | None = None) -> Any:
        if self.out is not None or self.left == 0:
            return None
        if self.taken == 0:
            self.first_generations = first_generations
        self.left -= 1
        self.taken += 1
        self.out = _FakeJob(self.stream, self.generations, self.gen_s)
        return self.out

    def abandon(self, job: Any) -> None:
        if job is self.out:
            self.out = None

    def next_is_refresh(self, defer_scheduled: bool = False) -> bool:
        return False  # (every job here is a run of generations, none a refresh of weights)


def test_short_jobs_nested_in_a_long_run_leave_it_half_of_the_worker() -> None:
    """An overloaded daemon: three streams whose short jobs never stop coming, one long run among them.
    Before the bound the long run waited for every short job between each of its generations (here ~4.4 s of
    wall time for 0.8 s of its own); now the short jobs run inside it take at most its own time."""
    from collections import Counter as _Counter

    from streamid.daemon.runner import JobRunner
    from streamid.daemon.slots import StreamSlot

    shorts = {f"s{i}": StreamSlot(_FakeIdent(f"s{i}", 10_000, 3, 0.01)) for i in range(3)}  # type: ignore[arg-type]
    long = StreamSlot(_FakeIdent("long", 1, 40, 0.02))  # type: ignore[arg-type]
    streams = {**shorts, "long": long}
    done: dict[str, list[float]] = {n: [] for n in streams}
    stop = threading.Event()
    runner = JobRunner(streams, DaemonConfig(), stop, _Counter(), lambda st, job, out: done[st.ident.stream].append(
        time.monotonic()))
    for name in ("s0", "s1", "s2", "long"):  # the short streams run once alone first: then they are known short
        runner.wake(name)
    t0 = time.monotonic()
    _work_until(runner, stop, lambda: bool(done["long"]))
    wall = done["long"][0] - t0
    nested = sum(st.nested_runs for st in shorts.values())
    assert nested >= 5  # short jobs did go between its generations
    # the rule, not this machine's speed: the short jobs run inside the long run took at most NESTED_SHARE times
    # its own time, plus the one that began just under the share (was: every short job between each generation,
    # ~4.4 s of wall time for 0.8 s of its own)
    from streamid.daemon.scheduler import NESTED_SHARE

    run = next(r for r in FAKE_RUNS if r.name == "long")
    one = max(r.took_s for r in FAKE_RUNS if r.name != "long")
    assert run.paused_s <= NESTED_SHARE * run.own_s + one, (run.paused_s, run.own_s, one, nested, wall)


def _work_until(runner: Any, stop: threading.Event, cond: Any, timeout_s: float = 20.0) -> None:
    """One worker thread serves ``runner``'s jobs until ``cond()`` holds (asserted within ``timeout_s``), then stops."""
    worker = threading.Thread(target=runner.worker_loop, daemon=True)
    worker.start()
    try:
        assert _wait_for(cond, timeout_s)
    finally:
        stop.set()
        runner.scheduler.notify_all()
        worker.join(10)


def _wait_for(cond: Any, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return bool(cond())


def test_a_long_run_lets_no_short_job_in_while_a_stream_waits_for_its_first_run() -> None:
    """First runs go before the served streams' next jobs: while a stream waits for its first run, the long run in
    progress lets no other stream's short job in between its generations; once none waits, it does again."""
    from collections import Counter as _Counter

    from streamid.daemon.runner import JobRunner
    from streamid.daemon.slots import StreamSlot

    FAKE_RUNS.clear()
    shorts = {f"s{i}": StreamSlot(_FakeIdent(f"s{i}", 10_000, 3, 0.01)) for i in range(3)}  # type: ignore[arg-type]
    long = StreamSlot(_FakeIdent("long", 1, 20, 0.02))  # type: ignore[arg-type]
    new = StreamSlot(_FakeIdent("new", 1, 20, 0.02))  # type: ignore[arg-type]
    streams = {**shorts, "long": long, "new": new}
    done: dict[str, list[float]] = {n: [] for n in streams}
    stop = threading.Event()
    runner = JobRunner(streams, DaemonConfig(), stop, _Counter(), lambda st, job, out: done[st.ident.stream].append(
        time.monotonic()))
    for name in ("s0", "s1", "s2", "long", "new"):  # every first run, in this order; "new" waits during "long"
        runner.wake(name)
    _work_until(runner, stop, lambda: bool(done["new"]))
    by_name = {r.name: r for r in FAKE_RUNS if r.name in ("long", "new")}
    assert by_name["long"].paused_s == 0.0  # "new" waited for its first run all along: nothing nested
    assert by_name["new"].paused_s > 0.0  # no first run waits any more: the short jobs go between its generations
    assert done["new"][0] > done["long"][0]
    # a first run while another stream waits for its own is shortened (FIRST_RUN_SHARE of the cold generations)
    from streamid.daemon.runner import FIRST_RUN_SHARE

    assert long.ident.first_generations == round(FIRST_RUN_SHARE * StreamConfig().cold_generations) == 200
    assert new.ident.first_generations is None and shorts["s0"].ident.first_generations is not None
