"""Bouc-Wen simulator: ground truth of the hysteretic benchmark, the exact hysteresis update, the linear part."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from streamid.errors import ConfigError
from streamid.sim.boucwen import (
    BENCHMARK_PERIOD_NS,
    BoucWenParams,
    bouc_wen_operator,
    integrate_bouc_wen,
    simulate_bouc_wen,
    simulate_bouc_wen_multisine,
    simulate_bouc_wen_periodic,
)

DATA = Path(__file__).parent / "data" / "bouc_wen_benchmark" / "bw_val_multisine.csv"


def test_reproduces_benchmark_multisine_within_one_percent() -> None:
    data = np.loadtxt(DATA, delimiter=",", skiprows=1)
    u, y_m = data[:, 2], data[:, 3]
    assert u.size == 8192
    tr = simulate_bouc_wen_periodic(u, BENCHMARK_PERIOD_NS, n_periods=3, upsample=20)
    err = tr.y - y_m
    nrmse_std = np.std(err) / np.std(y_m)  # the stricter of the two (std <= rms)
    nrmse_rms = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(y_m**2))
    assert nrmse_std < 0.01 and nrmse_rms < 0.01  # the requirement
    assert nrmse_std < 1e-3  # regression guard: measured 3.5e-4 (benchmark's own Newmark/filter level)
    # and the hysteresis matters: the linear oscillator alone is far off
    lin = simulate_bouc_wen_periodic(u, n_periods=3, params=BoucWenParams(alpha=0.0, beta=0.0))
    assert np.std(lin.y - y_m) / np.std(y_m) > 0.2


def _reference_z(x_fun, dx_fun, t_end: float, t_eval: np.ndarray, p: dict) -> np.ndarray:
    def rhs(t: float, z: np.ndarray) -> list[float]:
        v = dx_fun(t)
        zz = z[0]
        return [p["alpha"] * v - p["beta"] * (p["gamma"] * abs(v) * zz + p["delta"] * v * abs(zz))]

    sol = solve_ivp(rhs, (0.0, t_end), [0.0], method="DOP853", rtol=1e-12, atol=1e-14,
                    t_eval=t_eval, max_step=1e-3)
    return sol.y[0]


def test_operator_is_exact_for_nu_1() -> None:
    # smooth driving signal with several reversals of different amplitude; z crosses zero often
    p = {"alpha": 5e4, "beta": 1e3, "gamma": 0.8, "delta": -1.1}
    def x_fun(t):
        return 1e-3 * np.sin(2 * np.pi * t) + 4e-4 * np.sin(2 * np.pi * 3.3 * t)

    def dx_fun(t):
        return 2e-3 * np.pi * np.cos(2 * np.pi * t) + 4e-4 * 2 * np.pi * 3.3 * np.cos(2 * np.pi * 3.3 * t)

    t = np.linspace(0.0, 2.0, 20001)  # 1e-4 s: x monotone between samples except at reversals
    z = bouc_wen_operator(x_fun(t), **p)
    ref = _reference_z(x_fun, dx_fun, 2.0, t, p)
    assert np.max(np.abs(z - ref)) < 1e-6 * np.max(np.abs(ref))
    assert np.sum(np.diff(np.sign(z)) != 0) >= 4  # zero crossings exercised


def test_operator_general_nu_matches_reference() -> None:
    p = {"alpha": 1.0, "beta": 0.5, "gamma": 0.6, "delta": 0.3, "nu": 2.0}
    t = np.linspace(0.0, 1.0, 4001)
    x = 2.0 * np.sin(2 * np.pi * t)

    def rhs(tt, z):
        v = 4.0 * np.pi * np.cos(2 * np.pi * tt)
        a = abs(z[0]) ** 2
        return [p["alpha"] * v - p["beta"] * (p["gamma"] * abs(v) * abs(z[0]) * z[0] + p["delta"] * v * a)]

    ref = solve_ivp(rhs, (0, 1), [0.0], method="DOP853", rtol=1e-12, atol=1e-14, t_eval=t).y[0]
    z = bouc_wen_operator(x, **p)
    assert np.max(np.abs(z - ref)) < 1e-5 * np.max(np.abs(ref))


def test_linear_part_matches_lsim() -> None:
    p = BoucWenParams(alpha=0.0, beta=0.0)  # z stays 0: a linear oscillator
    h = 1.0 / 15000
    t = np.arange(6000) * h
    u = 30.0 * np.sin(2 * np.pi * 20 * t) + 10.0 * np.sign(np.sin(2 * np.pi * 7 * t))
    y, v, z = integrate_bouc_wen(u, h, p)
    _, y_ref, _ = signal.lsim(([1.0 / p.m], [1.0, p.c / p.m, p.k / p.m]), u, t, interp=True)
    assert np.all(z == 0.0)
    assert np.max(np.abs(y - y_ref)) < 1e-9 * np.max(np.abs(y_ref))


def test_hysteresis_dissipates_energy() -> None:
    h = 1.0 / 15000
    t = np.arange(int(0.5 / h)) * h
    y, v, z = integrate_bouc_wen(80.0 * np.sin(2 * np.pi * 10 * t), h)
    last = slice(-1500, None)  # the last 10 Hz cycle
    work = np.sum(z[last][:-1] * np.diff(y[last]))  # closed-loop integral of z dy (J)
    assert work > 0.0
    assert np.ptp(z) > 0.1 * np.ptp(80.0 * np.sin(2 * np.pi * 10 * t))


def test_multisine_device_seeded_and_settled() -> None:
    np.random.seed(0)
    a = simulate_bouc_wen_multisine(1500, 11)
    np.random.seed(1)
    b = simulate_bouc_wen_multisine(1500, np.random.default_rng(11))
    assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    assert np.std(a.u) == pytest.approx(50.0, rel=1e-9)
    assert np.all(np.diff(a.t_ns) == BENCHMARK_PERIOD_NS)
    # steady state: a longer lead-in changes nothing visible
    c = simulate_bouc_wen_multisine(1500, 11, settle_s=10.0)
    assert np.max(np.abs(a.y - c.y)) < 1e-4 * np.std(c.y)
    assert not np.array_equal(a.y, simulate_bouc_wen_multisine(1500, 12).y)


def test_interpolation_modes_and_errors() -> None:
    u = 50.0 * np.sin(2 * np.pi * 20 * np.arange(300) / 750)
    lin = simulate_bouc_wen(u, interpolation="linear").y
    zoh = simulate_bouc_wen(u, interpolation="zoh").y
    assert lin.shape == zoh.shape == (300,)
    assert 0 < np.max(np.abs(lin - zoh)) < 0.2 * np.max(np.abs(lin))
    with pytest.raises(ConfigError, match="interpolation"):
        simulate_bouc_wen(u, interpolation="cubic")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="n_periods"):
        simulate_bouc_wen_periodic(u, n_periods=1)
    with pytest.raises(ConfigError, match="nu"):
        BoucWenParams(nu=0.5)
    with pytest.raises(ConfigError, match="period_ns"):
        simulate_bouc_wen(u, 0)
