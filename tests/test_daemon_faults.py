"""Bad input and failed updates over real Zenoh: counted on the status key, never fatal.

One daemon serves five streams at once; each gets its own trouble (malformed
payloads, NaN, duplicates, reordering, gaps, a change of sample period, a
constant signal, a model that cannot pass validation, u and y on separate
keys).  Every fault must show up in that stream's status, the healthy streams
must keep publishing, and a degraded stream keeps its previous model.
"""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest
from conftest import endpoint

from streamid.transport.client import ModelSubscriber, latest_model, latest_status
from streamid.wire.codec import SampleBatch, encode
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings

BASE = StreamConfig(window_s=2.0, update_every_s=1.0, cold_generations=30, warm_generations=10, neurons=5,
                    max_lag_y=3, max_lag_u=3)
CFG = DaemonConfig(
    defaults=BASE,
    overrides=(("strict", StreamConfig(**{**BASE.to_dict(), "min_r2_osa": 0.9999999})),),
    workers=2,
    status_every_s=0.2,
)
B = 50  # samples per batch


@functools.lru_cache(maxsize=None)
def _record(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The simulated damper's (u, y), once per length and seed: the split stream's u and y batches are cut from
    the same record (simulating it is most of this module's setup, ~0.7 s a record, in a module that runs alone)."""
    _, u, y = get_device("mr_damper").simulate_seconds(seconds, seed=seed)
    u.setflags(write=False)  # shared by the batches cut from it: never changed in place
    y.setflags(write=False)
    return u, y


def batches(stream: str, n_batches: int, *, seed: int = 0, period: int | None = None, kind: str = "samples",
            k0: int = 0, batch: int = B) -> list[SampleBatch]:
    dev = get_device("mr_damper")
    u, y = _record((k0 + n_batches * batch) * dev.period_ns / 1e9 + 0.1, seed)
    p = period or dev.period_ns
    out = []
    for k in range(n_batches):
        i = (k0 + k * batch)
        ins = {"v": u[i : i + batch]} if kind in ("samples", "u") else {}
        outs = {"f": y[i : i + batch]} if kind in ("samples", "y") else {}
        out.append(SampleBatch(stream, k, i * p, p, None, ins, outs))
    return out


def tamper(b: SampleBatch, **arrays: np.ndarray) -> SampleBatch:
    ins = {k: arrays.get(k, v) for k, v in b.inputs.items()}
    outs = {k: arrays.get(k, v) for k, v in b.outputs.items()}
    return SampleBatch(b.stream, b.seq, b.t0_ns, b.period_ns, b.t_ns, ins, outs)


@pytest.fixture(scope="module")
def run() -> dict:
    ep = endpoint()
    daemon = Daemon(CFG, ZenohSettings(listen=(ep,))).start()
    connect = ZenohSettings(connect=(ep,))
    good = batches("good", 100)
    flaky = batches("flaky", 60, seed=1)
    flat = [tamper(b, v=np.full(B, 1.5)) for b in batches("flaky", 60, seed=1, k0=60 * B)]
    flat = [SampleBatch("flaky", 60 + i, b.t0_ns, b.period_ns, None, dict(b.inputs), dict(b.outputs))
            for i, b in enumerate(flat)]
    strict = batches("strict", 60, seed=2)
    p1 = batches("period", 60, seed=3)
    p2 = [SampleBatch("period", 60 + b.seq, b.t0_ns + 60 * B * 5_000_000, 10_000_000, None, dict(b.inputs),
                      dict(b.outputs)) for b in batches("period", 50, seed=3, period=10_000_000)]
    su = batches("split", 70, seed=4, kind="u", batch=35)
    sy = batches("split", 35, seed=4, kind="y", batch=70)
    seen: dict[str, list[int]] = {}
    with Bus(connect) as bus, ModelSubscriber(bus, "*", lambda up: seen.setdefault(up.stream, []).append(up.version)):
        pubs = {k: bus.publisher(f"streamid/{s}/{k2}") for k, (s, k2) in {
            "good": ("good", "samples"), "flaky": ("flaky", "samples"), "strict": ("strict", "samples"),
            "period": ("period", "samples"), "su": ("split", "u"), "sy": ("split", "y")}.items()}
        for p in pubs.values():
            assert p.wait_for_subscribers(10.0)
        # the faults on "good": each one exactly once, between healthy batches
        faults = {
            10: lambda: pubs["good"].put(b"\x08\x01\x12\x04good\x3a\xff"),  # truncated
            12: lambda: pubs["good"].put(b"\x08\x09\x12\x04good"),  # unknown wire-format version
            14: lambda: pubs["good"].put(np.random.default_rng(0).bytes(300)),  # random bytes
            16: lambda: pubs["good"].put(encode(tamper(good[16], f=np.r_[np.inf, good[16].outputs["f"][1:]]))),
            18: lambda: pubs["good"].put(encode(tamper(good[18], v=np.full(B, 1e300)))),
            20: lambda: pubs["good"].put(encode(good[19])),  # duplicate of the previous batch
            22: lambda: pubs["good"].put(encode(good[5])),  # an old batch again (duplicate, long after)
            24: lambda: pubs["good"].put(encode(SampleBatch("other", 1, 0, 5_000_000, None, {"v": np.ones(3)},
                                                            {"f": np.ones(3)}))),  # wrong stream name in the batch
        }
        skipped = {16, 18, 40, 41}  # 16 and 18 go as tampered copies; 40-41 never sent: a gap
        for k in range(100):
            if k in faults:
                faults[k]()
            if k not in skipped:
                pubs["good"].put(encode(good[k]))
            if k < 60:
                pubs["flaky"].put(encode(flaky[k]))
                pubs["strict"].put(encode(strict[k]))
                pubs["period"].put(encode(p1[k]))
            elif k < 120:
                pubs["flaky"].put(encode(flat[k - 60]))
                if k - 60 < len(p2):
                    pubs["period"].put(encode(p2[k - 60]))
            if k < 70:
                pubs["su"].put(encode(su[k]))
            if k < 70 and k % 2 == 1:  # y in batches twice as long, sent every other round: y never leads
                pubs["sy"].put(encode(sy[k // 2]))
            time.sleep(0.02)
        deadline = time.monotonic() + 30
        status: dict[str, dict] = {}
        while time.monotonic() < deadline:
            status = {s: latest_status(bus, s, timeout_s=1.0) or {} for s in ("good", "flaky", "strict", "period", "split")}
            if all(st and not st["busy"] and not st["windows"]["pending"] and st["samples_in"] > 0
                   and sum(st["identifications"].values()) > 0 for st in status.values()):
                break
            time.sleep(0.1)
        latest = {s: latest_model(connect, s, timeout_s=1.0, default=None) for s in ("good", "flaky", "strict")}
    daemon.stop()
    return {"status": status, "seen": seen, "latest": latest}


def test_healthy_stream_counts_every_fault_and_keeps_publishing(run: dict) -> None:
    st = run["status"]["good"]
    assert st["bad"] == {"decode": 3, "nonfinite": 1, "magnitude": 1, "duplicate": 2, "stream_mismatch": 1}
    assert st["gaps"] >= 1 and st["resets"].get("gap", 0) >= 1
    assert st["degraded"] is False
    assert len(run["seen"]["good"]) >= 2 and st["version"] == run["seen"]["good"][-1]


def test_constant_signal_degrades_but_keeps_the_previous_model(run: dict) -> None:
    st = run["status"]["flaky"]
    assert st["degraded"] is True and "constant" in st["degraded_reason"]
    assert st["drop_reasons"].get("constant_signal", 0) >= 1
    assert st["version"] >= 1
    assert run["latest"]["flaky"] is not None and run["latest"]["flaky"].version == st["version"]


def test_model_failing_validation_is_not_published(run: dict) -> None:
    st = run["status"]["strict"]
    assert st["degraded"] is True and "min_r2_osa" in st["degraded_reason"]
    assert st["identifications"]["rejected"] >= 1 and st["identifications"]["accepted"] == 0
    assert st["version"] == 0 and run["latest"]["strict"] is None and "strict" not in run["seen"]


def test_period_change_resets_the_stream(run: dict) -> None:
    st = run["status"]["period"]
    assert st["resets"].get("period") == 1 and st["period_ns"] == 10_000_000
    assert st["version"] >= 2  # identified before and after the change


def test_u_and_y_on_separate_keys_are_aligned(run: dict) -> None:
    st = run["status"]["split"]
    assert st["bad_total"] == 0 and st["unaligned"] == 0
    assert st["samples_in"] == 70 * 35 + 35 * 70  # every u and every y sample written
    assert st["version"] >= 1 and st["inputs"] == ["v"] and st["outputs"] == ["f"]
