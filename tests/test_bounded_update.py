"""Bounded work per online update (issue 38 item 1): the search sees a bounded, stratified set of rows, the chosen
model is refitted on every row (a QR streamed in blocks), and the admission estimate bounds the measured peak.

The end-to-end case is a real daemon with its default search and memory bound, fed a simulated 20 kHz piezo
stream whose 10 s window was refused before (~1316 MiB by the old estimate against the default 512 MiB).
"""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from conftest import endpoint, stop_process, wait_until, start_daemon

from streamid.daemon.admission import check_batch, identification_bytes, stream_bytes
from streamid.engine.fit import rbf
from streamid.engine.settings import RIDGE
from streamid.engine.warmup import warm_up_kernels
from streamid.engine.choice.selection import refit_weights
from streamid.errors import ConfigError
from streamid.online.rows import SEARCH_ROWS, informative_rows, search_row_bound
from streamid.online.stream_config import StreamConfig
from streamid.online.update import identify_window, signature_of
from streamid.online.window_types import Window
from streamid.sim.piezo import simulate_piezo
from streamid.transport import Bus, ZenohSettings
from streamid.wire.codec import SampleBatch, encode

PERIOD_NS = 50_000  # 20 kHz
MiB = 1 << 20


def _piezo_window(n: int, seed: int = 0) -> Window:
    tr = simulate_piezo(n, seed)
    return Window("piezo", 1, 0, 0, PERIOD_NS, ("voltage_V",), ("deflection_um",),
                  np.ascontiguousarray(tr.u.reshape(n, 1)), np.ascontiguousarray(tr.y.reshape(n, 1)), 0, 0)


# --------------------------------------------------------------------------- the rows
def test_one_row_per_stratum_covering_the_whole_window() -> None:
    rng = np.random.default_rng(3)
    s = informative_rows(100_000, 4096, rng)
    assert s is not None and s.rows.size == 4096 and s.of == 100_000
    assert np.all(np.diff(s.rows) > 0) and s.rows[0] >= 0 and s.rows[-1] < 100_000
    edges = (np.arange(4097) * 100_000) // 4096
    assert np.array_equal(np.searchsorted(edges, s.rows, side="right") - 1, np.arange(4096))  # one in each stratum
    assert len(set(np.diff(s.rows).tolist())) > 10  # drawn within the strata, not a fixed stride
    again = informative_rows(100_000, 4096, np.random.default_rng(3))
    assert again is not None and np.array_equal(again.rows, s.rows)
    assert informative_rows(4096, 4096, rng) is None and informative_rows(10**6, 0, rng) is None
    with pytest.raises(ConfigError, match="row bound must be 0 .* or >= 2; got 1"):
        informative_rows(10, 1, rng)


def test_the_bound_follows_the_model_size_not_the_sample_rate() -> None:
    assert search_row_bound(10, 10, 10, 1, {}) == SEARCH_ROWS == 4096
    assert search_row_bound(30, 10, 10, 4, {}) == 128 * (30 + 50 + 1)
    assert search_row_bound(10, 10, 10, 1, {"search_rows": 0}) == 0
    assert search_row_bound(10, 10, 10, 1, {"search_rows": 500}) == 500
    with pytest.raises(ConfigError, match="engine.search_rows must be an integer >= 0 .*; got -3"):
        search_row_bound(10, 10, 10, 1, {"search_rows": -3})


# --------------------------------------------------------------------------- streamed numerics
def test_activations_in_blocks_are_the_one_pass_values_to_the_bit() -> None:
    rng = np.random.default_rng(1)
    r, c, w = rng.uniform(-1, 1, (rbf.BLOCK_ROWS * 2 + 17, 5)), rng.uniform(-1, 1, (7, 5)), rng.uniform(0.2, 2, 7)
    direct = np.exp(-((r[:, None, :] - c[None]) ** 2).sum(axis=2) / (2.0 * w[None, :] ** 2))
    assert np.array_equal(rbf.activations(r, c, w), direct)


@pytest.mark.parametrize("ridge", [1e-10, 1e-6, 0.0])
def test_streamed_least_squares_is_the_one_shot_solution(monkeypatch: pytest.MonkeyPatch, ridge: float) -> None:
    rng = np.random.default_rng(2)
    n = 3 * rbf.FIT_BLOCK_ROWS + 123  # three full blocks and a short one
    r, c, w = rng.uniform(-1, 1, (n, 4)), rng.uniform(-1, 1, (6, 4)), rng.uniform(0.3, 2, 6)
    phi = rbf.activations(r, c, w)
    y = phi @ rng.standard_normal(6) + 0.3 * r[:, 0] + 0.01 * rng.standard_normal(n)
    streamed = rbf.fit_weights(phi, y, ridge), rbf.fit_linear_rbf(phi, r, y, ridge)
    monkeypatch.setattr(rbf, "FIT_BLOCK_ROWS", 10 * n)  # one QR of the whole design, as before
    whole = rbf.fit_weights(phi, y, ridge), rbf.fit_linear_rbf(phi, r, y, ridge)
    np.testing.assert_allclose(streamed[0], whole[0], rtol=1e-9, atol=1e-9 * np.abs(whole[0]).max())
    for a, b in zip(streamed[1], whole[1]):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())


# --------------------------------------------------------------------------- one update of a long window
def test_a_long_window_is_searched_on_the_bound_and_refitted_on_every_row() -> None:
    warm_up_kernels()
    w = _piezo_window(20_000)
    # (no long linear part: its weights come from its own least squares, streamid.engine.choice.longlinear)
    cfg = StreamConfig(window_samples=20_000, cold_generations=8, warm_generations=3, engine=(("long_linear", 0),))
    out = identify_window(w, cfg, version=1)
    assert out.kind == "identified" and out.model is not None and out.summary is not None, out.reason
    n_est = out.window_meta["n_estimation"]
    assert out.model.metrics["search_rows"] == {"rows": 4096, "of": n_est - 10, "bound": 4096, "sampling": "stratified"}
    u_est, y_est = w.u[:n_est], w.y[:n_est, 0]
    again = refit_weights(out.model, u_est, y_est, RIDGE)
    np.testing.assert_allclose(out.model.weights, again.weights, rtol=1e-6,
                               atol=1e-6 * np.abs(again.weights).max())  # the weights of every row, not the sample's
    assert out.summary.metrics["r2_fr_val"] > 0.9, out.summary.metrics
    warm = identify_window(w, cfg, version=2, warm_state=out.state, warm_signature=signature_of(w, cfg, "deflection_um"))
    assert warm.kind == "identified" and warm.warm and warm.model is not None
    assert warm.model.metrics["search_rows"]["rows"] == 4096
    short = identify_window(_piezo_window(3000), StreamConfig(window_samples=3000, cold_generations=4), version=1)
    assert short.model is not None and "search_rows" not in short.model.metrics  # under the bound: every row
    every = identify_window(w, StreamConfig(window_samples=20_000, cold_generations=4,
                                            engine=(("long_linear", 0), ("search_rows", 0))), version=1)
    assert every.model is not None and "search_rows" not in every.model.metrics  # search_rows = 0: every row
    fewer = identify_window(w, StreamConfig(window_samples=20_000, cold_generations=4,
                                            engine=(("long_linear", 0), ("search_rows", 500))), version=1)
    assert fewer.model is not None and fewer.model.metrics["search_rows"]["rows"] == 500


@pytest.mark.parametrize("n", [3000, 60_000])
def test_the_admission_estimate_bounds_the_measured_peak(n: int) -> None:
    """tracemalloc peak of a cold and a warm update <= the estimate <= 2x it, on a window under the bound and one
    15x over it (the estimate grew 8.8 kB a row before; now its search part is bounded)."""
    warm_up_kernels()
    w = _piezo_window(n, seed=1)
    cfg = StreamConfig(window_samples=n, cold_generations=4, warm_generations=2)
    first = identify_window(w, cfg, version=1)
    assert first.kind == "identified", first.reason
    peaks = []
    for kw in ({}, {"warm_state": first.state, "warm_signature": signature_of(w, cfg, "deflection_um"),
                    "champion": first.model}):
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            out = identify_window(w, cfg, version=2, **kw)  # type: ignore[arg-type]
            peaks.append(tracemalloc.get_traced_memory()[1] - base)
        finally:
            tracemalloc.stop()
        assert out.kind == "identified", out.reason
    est = identification_bytes(n, 1, 1, cfg)
    assert max(peaks) <= est <= 2 * max(peaks), (n, peaks, est)


def test_a_20_khz_ten_second_window_fits_the_default_bound() -> None:
    cfg = StreamConfig()  # the daemon's defaults: 10 s windows
    batch = SampleBatch("piezo", 0, 0, PERIOD_NS, None, {"v": np.zeros(200)}, {"x": np.zeros(200)})
    assert check_batch(batch, cfg, max_channels=64, max_bytes=512 * MiB) is None  # refused before (~1316 MiB)
    assert identification_bytes(200_000, 1, 1, cfg) < 400 * MiB
    assert stream_bytes(200_000, 1, 1, cfg) < 512 * MiB


# --------------------------------------------------------------------------- a real daemon
CONFIG = """
[daemon]
status_every_s = 0.5

[defaults]
cold_generations = 60
warm_generations = 5
"""


def test_a_daemon_with_default_bounds_identifies_a_20_khz_stream(tmp_path: Path) -> None:
    """The daemon's default window (10 s) and memory bound (512 MiB), fewer generations to keep the test short."""
    ep = endpoint()
    proc = start_daemon(tmp_path, ep, CONFIG)
    try:
        tr = simulate_piezo(220_000, 4)
        with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as bus:
            pub = bus.publisher("streamid/piezo/samples", block=True)
            assert pub.wait_for_subscribers(30)
            for k in range(0, 220_000, 2000):
                pub.put(encode(SampleBatch("piezo", k // 2000, k * PERIOD_NS, PERIOD_NS, None,
                                           {"voltage_V": tr.u[k : k + 2000]}, {"deflection_um": tr.y[k : k + 2000]})))
            got: list[dict[str, object]] = []

            def model() -> bool:
                got[:] = [json.loads(p) for _, p in bus.get("streamid/piezo/model", 1.0)]
                return bool(got)

            assert wait_until(model, 120), proc.stderr
            doc = got[0]
            metrics = doc["model"]["metrics"]  # type: ignore[index]
            assert metrics["search_rows"] == {"rows": 4096, "of": 139_990, "bound": 4096, "sampling": "stratified"}
            assert doc["window"]["n_samples"] == 200_000 and doc["window"]["period_ns"] == PERIOD_NS  # type: ignore[index]
            status = [json.loads(p) for _, p in bus.get("streamid/piezo/status", 2.0)]
            assert status and not status[0].get("bad", {}).get("too_large_window"), status
    finally:
        stop_process(proc)
