"""A log replayed at max speed with a bounded queue of pending windows, end to end over real Zenoh.

The bundled real MR damper log (3499 samples at 200 Hz) is replayed back to
back (it arrives in milliseconds, far faster than identification) onto two
streams of one daemon (real session on tcp/127.0.0.1:PORT, multicast off):

* ``mr_all`` with ``max_pending_windows = 64``: every one of the 29 windows
  (3 s, every 0.5 s) is identified, in order, the first cold and the others
  warm-started; each challenger replaces the champion or is rejected, and every
  published model was fitted on exactly its window's samples of the log;
* ``mr_few`` with ``max_pending_windows = 3``: the queue never holds more than
  three windows (its high-water mark and bytes, as published on the status key,
  stay within the documented bound), the rest are counted as coalesced.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
from conftest import endpoint

from replay.player import ReplayConfig, replay_log
from streamid.transport.client import ModelSubscriber, latest_status
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.transport.updates import ModelUpdate
from streamid.daemon.service import Daemon
from streamid.engine.validation import r2
from streamid.logs import bundled_log, read_log_arrays
from streamid.transport import Bus, ZenohSettings

BASE = StreamConfig(window_s=3.0, update_every_s=0.5, cold_generations=100, warm_generations=8, neurons=5,
                    max_lag_y=3, max_lag_u=3, seed=1)
CFG = DaemonConfig(
    streams=("mr_all", "mr_few"),
    defaults=BASE,
    overrides=(("mr_all", dataclasses.replace(BASE, max_pending_windows=64)),
               ("mr_few", dataclasses.replace(BASE, max_pending_windows=3))),
)
N_LOG, W, H = 3499, 600, 100  # samples in the log, window and hop in samples
N_WINDOWS = (N_LOG - W) // H + 1  # 29
WINDOW_BYTES = W * 2 * 8  # one input, one output, float64


@pytest.fixture(scope="module")
def run() -> dict[str, object]:
    ep = endpoint()
    daemon = Daemon(CFG, ZenohSettings(listen=(ep,))).start()
    got: dict[str, list[ModelUpdate]] = {"mr_all": [], "mr_few": []}
    status: dict[str, dict | None] = {}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, \
                ModelSubscriber(bus, "mr_all", got["mr_all"].append, fetch_latest=False), \
                ModelSubscriber(bus, "mr_few", got["mr_few"].append, fetch_latest=False):
            for name in ("mr_all", "mr_few"):
                replay_log(bundled_log("mr_damper.mcap"), bus=bus,
                           config=ReplayConfig(max_speed=True, stream_map=(("mr_damper", name),)))
            deadline = time.monotonic() + 40
            while time.monotonic() < deadline:
                status = {s: latest_status(bus, s, timeout_s=1.0) for s in got}
                if all(st and not st["busy"] and not st["windows"]["pending"] and st["samples_in"] == N_LOG
                       for st in status.values()):
                    break
                time.sleep(0.1)
            time.sleep(0.3)  # the last model put before the status said idle is on its way
    finally:
        daemon.stop()
    return {"got": got, "status": status}


def test_every_window_of_a_max_speed_replay_gets_a_model_in_order(run: dict) -> None:
    ups: list[ModelUpdate] = run["got"]["mr_all"]
    st = run["status"]["mr_all"]
    assert st["windows"]["closed"] == N_WINDOWS == 29
    ids = st["identifications"]
    assert st["windows"]["coalesced"] == 0 and ids["accepted"] + ids["rejected"] == N_WINDOWS  # every window decided
    assert ids["failed"] == ids["dropped"] == 0 and sum(st["decisions"].values()) == N_WINDOWS
    assert st["decisions"].get("not_better", 0) == ids["rejected"] - st["decisions"].get("validation", 0)
    assert [u.version for u in ups] == list(range(1, ids["accepted"] + 1))
    numbers = [u.window["number"] for u in ups]
    assert numbers[0] == 1 and numbers == sorted(set(numbers)) and numbers[-1] <= N_WINDOWS
    assert all(u.window["coalesced_before"] == 0 for u in ups)
    t0 = [u.window["t0_ns"] for u in ups]
    assert np.all(np.diff(t0) % (H * 5_000_000) == 0)  # on the hop grid
    assert not ups[0].warm and all(u.warm for u in ups[1:])
    codes = [u.document["decision"]["code"] for u in ups]
    assert codes[0] == "first" and set(codes[1:]) <= {"better", "champion_invalid"}
    assert 2 <= st["windows"]["pending_windows_peak"] <= 64  # the windows really queued behind the cold run
    log = read_log_arrays(bundled_log("mr_damper.mcap"))
    for up in ups:  # each model was fitted and validated on exactly its window of the log
        i0 = int(np.searchsorted(log.t_ns, up.window["t0_ns"]))
        assert log.t_ns[i0] == up.window["t0_ns"] and log.t_ns[i0 + W - 1] == up.window["t_end_ns"]
        n_val = up.window["n_validation"]
        u = log.inputs["velocity_cm_s"][i0 + W - n_val: i0 + W]
        y = log.outputs["force_N"][i0 + W - n_val: i0 + W]
        L = up.model.max_lag
        fr = up.model.simulate(u, y[:L])
        assert r2(y[L:], fr[L:]) == pytest.approx(up.metrics["r2_fr_val"], abs=1e-9)
        assert up.metrics["r2_osa_val"] >= 0.95


def test_a_small_bound_holds_the_queue_and_counts_the_rest(run: dict) -> None:
    ups: list[ModelUpdate] = run["got"]["mr_few"]
    w = run["status"]["mr_few"]["windows"]
    assert w["max_pending_windows"] == 3 and w["pending_bytes_max"] == 3 * WINDOW_BYTES
    assert w["pending_windows_peak"] == 3  # filled while the cold run ran, never beyond
    assert w["pending_bytes_peak"] == (W + 2 * H) * 2 * 8  # three overlapping windows: their samples held once
    assert w["pending_windows"] == 0 and w["pending_bytes"] == 0
    assert w["closed"] == N_WINDOWS
    ids = run["status"]["mr_few"]["identifications"]
    identified = ids["accepted"] + ids["rejected"]
    assert 3 <= identified < N_WINDOWS and w["coalesced"] == N_WINDOWS - identified
    assert [u.version for u in ups] == list(range(1, ids["accepted"] + 1))
    assert w["emitted"] == N_WINDOWS and not run["status"]["mr_few"]["windows"]["live"]
