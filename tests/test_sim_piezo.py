"""Piezo micromanipulator simulator: hysteresis loop, resonance, noise, excitation, causality, seeding."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.errors import ConfigError
from streamid.sim.piezo import PiezoParams, piezo_excitation, simulate_piezo, simulate_piezo_input

FS = 20_000


def _sine_response(amp_v: float, freq_hz: float, seconds: float, params: PiezoParams) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(seconds * FS)) / FS
    u = amp_v * np.sin(2 * np.pi * freq_hz * t)
    return u, simulate_piezo_input(u, params=params).y


def test_low_frequency_hysteresis_loop() -> None:
    u, y = _sine_response(100.0, 1.0, 3.0, PiezoParams())
    uu, yy = u[2 * FS :], y[2 * FS :]  # third cycle
    area = abs(np.sum(0.5 * (yy[1:] + yy[:-1]) * np.diff(uu)))  # |closed-loop integral of y du|, um V
    assert area > 0.05 * np.ptp(yy) * np.ptp(uu)
    up = np.flatnonzero((uu[:-1] < 0) & (uu[1:] >= 0))
    down = np.flatnonzero((uu[:-1] > 0) & (uu[1:] <= 0))
    width = abs(yy[down[0]] - yy[up[0]])  # two branches at 0 V
    assert 0.08 * np.ptp(yy) < width < 0.2 * np.ptp(yy)  # documented: 12 % at +-100 V
    assert 40.0 < np.ptp(yy) < 70.0  # documented: 52.6 um stroke for +-100 V
    # without hysteresis parameters there is no loop
    u0, y0 = _sine_response(100.0, 1.0, 3.0, PiezoParams(hyst_a=0.0))
    area0 = abs(np.sum(0.5 * (y0[2 * FS + 1 :] + y0[2 * FS : -1]) * np.diff(u0[2 * FS :])))
    assert area0 < 0.01 * area


def test_structural_resonance() -> None:
    p = PiezoParams(sensor_bandwidth_hz=None)
    gains = {}
    for f in (100.0, 700.0, 1000.0, 1400.0):
        u, y = _sine_response(1.0, f, 0.5, p)
        gains[f] = 0.5 * np.ptp(y[FS // 4 :])  # after the transient (~5 / (zeta wn) = 27 ms)
    assert gains[1000.0] > 8.0 * gains[100.0]
    assert gains[1000.0] > 2.0 * gains[700.0] and gains[1000.0] > 2.0 * gains[1400.0]


def test_sensor_noise_level_and_output_causality() -> None:
    u = piezo_excitation(FS, 3)
    clean = simulate_piezo_input(u).y
    noisy = simulate_piezo_input(u, np.random.default_rng(5)).y
    assert np.std(noisy - clean) == pytest.approx(0.04, rel=0.05)
    u2 = u.copy()
    u2[1000] += 20.0
    y2 = simulate_piezo_input(u2).y
    assert np.array_equal(clean[:1001], y2[:1001])  # y[k] does not see u[k]
    assert np.max(np.abs(y2[1001:1010] - clean[1001:1010])) > 0.0


def test_excitation_covers_hysteresis_and_dynamics() -> None:
    n = 10 * FS
    u = piezo_excitation(n, 4)
    assert np.max(np.abs(u)) == pytest.approx(100.0)
    spec = np.abs(np.fft.rfft(u)) ** 2
    f = np.fft.rfftfreq(n, 1 / FS)
    low = spec[(f >= 0.5) & (f <= 20)].sum()
    res = spec[(f >= 800) & (f <= 1200)].sum()
    total = spec[1:].sum()
    assert low > 0.8 * total  # large quasi-static loops dominate
    # and the 1 kHz mode is excited: by design the high band (RMS ratio 0.08, flat on 20-3000 Hz)
    # puts 0.08^2 / (1 + 0.08^2) * 400/2980 = 8.5e-4 of the power in 800-1200 Hz
    assert res / total == pytest.approx(0.08**2 / (1 + 0.08**2) * 400 / 2980, rel=0.2)
    assert spec[f > 3100].sum() < 1e-9 * total  # nothing beyond the top band


def test_simulate_piezo_seeded_and_global_rng_unused() -> None:
    np.random.seed(0)
    a = simulate_piezo(3 * FS, 8)
    np.random.seed(1)
    before = np.random.get_state()[1].copy()
    b = simulate_piezo(3 * FS, np.random.default_rng(8))
    assert np.array_equal(np.random.get_state()[1], before)
    assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    assert not np.array_equal(a.y, simulate_piezo(3 * FS, 9).y)
    assert a.t_ns.dtype == np.int64 and np.all(np.diff(a.t_ns) == 50_000) and a.t_ns[0] == 0
    assert np.all(np.isfinite(a.y)) and 5.0 < np.ptp(a.y) < 80.0


def test_bad_parameters() -> None:
    with pytest.raises(ConfigError, match="sensor_bandwidth_hz"):
        PiezoParams(sensor_bandwidth_hz=12_000.0)
    with pytest.raises(ConfigError, match="resonance_hz"):
        PiezoParams(resonance_hz=-1.0)
    with pytest.raises(ConfigError, match="no frequency line"):
        piezo_excitation(100, 1)  # 5 ms record: no line in 0.5-20 Hz
    with pytest.raises(ConfigError, match="finite"):
        simulate_piezo_input([0.0, np.inf])
