"""MR damper simulator (Spencer et al. 1997): force range, hysteresis, integration accuracy, seeding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from streamid.errors import ConfigError
from streamid.sim.mrdamper import MRDamperParams, mr_damper_force, simulate_mr_damper, velocity_spectrum


def _sine_spectra(n: int, p: MRDamperParams, freq_hz: float, amp_cm: float):
    """Spectra of x = amp sin(2 pi f t) on an n-sample periodic grid (f must be a DFT line)."""
    k = int(round(freq_hz * n * p.period_s))
    x_spec = np.zeros(n // 2 + 1, dtype=complex)
    x_spec[k] = -0.5j * amp_cm * n
    f = np.fft.rfftfreq(n, p.period_s)
    return 2j * np.pi * f * x_spec, x_spec


def test_sinusoidal_test_is_hysteretic_and_grows_with_voltage() -> None:
    n = 400  # 2 s at 200 Hz; 2.5 Hz, 1.5 cm: one of Spencer et al.'s test motions
    peaks = []
    for volt in (0.0, 1.0, 2.0):
        p = MRDamperParams(voltage_v=volt)
        v_spec, x_spec = _sine_spectra(n, p, 2.5, 1.5)
        v, f = mr_damper_force(v_spec, x_spec, n, p, settle_samples=2000)
        x = np.fft.irfft(x_spec, n)
        dx = np.diff(np.concatenate([x, x[:1]]))
        work = np.sum(0.5 * (f + np.roll(f, -1)) * dx)  # closed-loop integral of F dx over 5 cycles, N cm
        assert work > 0.0  # energy is dissipated
        # force-velocity: at the same velocity the force differs between accelerating and decelerating
        i_acc = np.argmin(np.abs(v[:80] - 0.0) + 1e3 * (np.gradient(v)[:80] < 0))
        i_dec = np.argmin(np.abs(v[:80] - 0.0) + 1e3 * (np.gradient(v)[:80] > 0))
        assert abs(f[i_acc] - f[i_dec]) > 50.0
        peaks.append(np.max(np.abs(f - f.mean())))
    assert peaks[0] < peaks[1] < peaks[2]
    assert 100.0 < peaks[0] and peaks[2] < 3000.0  # hundreds of N up to ~1.5 kN, as the prototype


def test_default_record_force_range_and_preload() -> None:
    t_ns, v, f = simulate_mr_damper(800, 1, settle_s=10.0)
    assert np.std(v) == pytest.approx(6.0, rel=1e-9)
    assert np.mean(f) == pytest.approx(-5.0 * 14.3, abs=15.0)  # accumulator preload k1 (x - x0)
    assert 300.0 < np.max(np.abs(f - np.mean(f))) < 2000.0
    assert t_ns.dtype == np.int64 and np.all(np.diff(t_ns) == 5_000_000)


def test_rk4_substeps_converged_and_match_independent_solver() -> None:
    p = MRDamperParams()
    n = 400
    v_spec, x_spec = velocity_spectrum(n, p, 3)
    v1, f1 = mr_damper_force(v_spec, x_spec, n, p)
    v2, f2 = mr_damper_force(v_spec, x_spec, n, p, substeps=200)
    assert np.max(np.abs(f1 - f2)) < 1e-4 * np.std(f2)
    # the equations written out again, the motion as an explicit sum of sinusoids, scipy's LSODA
    lines = np.flatnonzero(np.abs(v_spec) > 0)
    w = 2 * np.pi * np.fft.rfftfreq(n, p.period_s)[lines]
    cx, cv = 2 * x_spec[lines] / n, 2 * v_spec[lines] / n
    c0, c1, al = p.c0a + p.c0b, p.c1a + p.c1b, p.alpha_a + p.alpha_b  # 1 V

    def xv(t: float) -> tuple[float, float]:
        e = np.exp(1j * w * t)
        return float(np.real(cx @ e)), float(np.real(cv @ e))

    def rhs(t: float, s: np.ndarray) -> list[float]:
        x, xd = xv(t)
        yd = (al * s[1] + c0 * xd + p.k0 * (x - s[0])) / (c0 + c1)
        r = xd - yd
        return [yd, -p.gamma * abs(r) * s[1] * abs(s[1]) - p.beta * r * s[1] ** 2 + p.a * r]

    m = 100  # first 0.5 s, started at rest like mr_damper_force without settling
    t_eval = np.arange(m) * p.period_s
    sol = solve_ivp(rhs, (0, t_eval[-1]), [xv(0.0)[0], 0.0], method="LSODA", rtol=1e-9, atol=1e-12,
                    t_eval=t_eval)
    xs = np.array([xv(t) for t in t_eval])
    yd = (al * sol.y[1] + c0 * xs[:, 1] + p.k0 * (xs[:, 0] - sol.y[0])) / (c0 + c1)
    f_ref = c1 * yd + p.k1 * (xs[:, 0] - p.x0)
    assert np.max(np.abs(f1[:m] - f_ref)) < 1e-4 * np.std(f_ref)  # measured 3.7e-5


def test_seeded_and_global_rng_unused() -> None:
    np.random.seed(3)
    before = np.random.get_state()[1].copy()
    a = simulate_mr_damper(400, 21, settle_s=5.0)
    assert np.array_equal(np.random.get_state()[1], before)
    np.random.seed(4)
    b = simulate_mr_damper(400, np.random.default_rng(21), settle_s=5.0)
    assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    assert not np.array_equal(a.y, simulate_mr_damper(400, 22, settle_s=5.0).y)


def test_bad_parameters() -> None:
    with pytest.raises(ConfigError, match="band_hz"):
        MRDamperParams(band_hz=(5.0, 150.0))
    with pytest.raises(ConfigError, match="voltage_v"):
        MRDamperParams(voltage_v=-1.0)
    with pytest.raises(ConfigError, match="no frequency line"):
        simulate_mr_damper(10, 1)  # 50 ms record: lines every 20 Hz, none in 0.5-10 Hz
