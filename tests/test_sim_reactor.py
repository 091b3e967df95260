"""Polymerization reactor simulator (paper eq. 17): fixed point, accuracy, range, indexing, seeding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from streamid.errors import ConfigError
from streamid.sim.reactor import (
    ReactorParams,
    reactor_output,
    reactor_states,
    reactor_steady_state,
    simulate_reactor,
    simulate_reactor_input,
)


def _rhs(_t: float, z: np.ndarray, u: float) -> list[float]:
    """Eq. (17) written out independently of the module."""
    z1, z2, z3, z4 = z
    q = np.sqrt(z2)
    return [
        10.0 * (6.0 - z1) - 2.4568 * q,
        80.0 * u - 10.1022 * z2,
        0.0024121 * z1 * q + 0.112191 * z2 - 10.0 * z3,
        245.978 * z1 * q - 10.0 * z4,
    ]


@pytest.mark.parametrize("u", [0.007, 0.011, 0.015])
def test_fixed_point_zeroes_the_derivatives(u: float) -> None:
    z = reactor_steady_state(u)
    assert np.allclose(_rhs(0.0, z, u), 0.0, atol=1e-12 * np.abs(z).max())


def test_constant_input_stays_at_fixed_point() -> None:
    zs = reactor_steady_state(0.013)
    z = reactor_states(np.full(40, 0.013), zs)
    assert np.max(np.abs(z / zs - 1.0)) < 1e-12


def test_mean_input_output_value() -> None:
    # analytical fixed point for u = 0.011 (worked by hand: z2 = 0.88/10.1022, ...): y* = 30 753
    y = reactor_output(reactor_steady_state(0.011))
    assert y == pytest.approx(30753.0, abs=1.0)


def test_matches_tight_solve_ivp_per_hold_interval() -> None:
    u = np.random.default_rng(7).uniform(0.007, 0.015, 60)
    z = reactor_states(u)
    ref = [reactor_steady_state(0.011)]
    for uk in u:
        sol = solve_ivp(_rhs, (0.0, 0.2), ref[-1], method="DOP853", rtol=1e-13, atol=1e-16, args=(uk,))
        ref.append(sol.y[:, -1])
    ref_arr = np.array(ref)
    assert np.max(np.abs(z / ref_arr - 1.0)) < 1e-9
    assert np.max(np.abs(reactor_output(z) / reactor_output(ref_arr) - 1.0)) < 1e-9


def test_output_range_as_in_the_paper() -> None:
    t_ns, u, y = simulate_reactor(960, np.random.default_rng(0))
    assert u.min() >= 0.007 and u.max() <= 0.015
    # every output lies between the fixed points of the extreme inputs (27 487 .. 35 871),
    # the paper's "roughly 2.6e4 .. 3.4e4"
    lo = reactor_output(reactor_steady_state(0.015))
    hi = reactor_output(reactor_steady_state(0.007))
    assert 2.6e4 < lo <= y.min() and y.max() <= hi < 3.6e4
    assert np.ptp(y) > 0.6 * (hi - lo)


def test_sample_times_and_lengths() -> None:
    t_ns, u, y = simulate_reactor(960, 3)
    assert t_ns.dtype == np.int64 and u.shape == y.shape == t_ns.shape == (960,)
    assert t_ns[0] == 0 and np.all(np.diff(t_ns) == 200_000_000)


def test_output_depends_only_on_past_inputs() -> None:
    u = np.random.default_rng(1).uniform(0.007, 0.015, 30)
    y0 = simulate_reactor_input(u).y
    u2 = u.copy()
    u2[10] = 0.015 if u[10] < 0.011 else 0.007
    y2 = simulate_reactor_input(u2).y
    assert np.array_equal(y0[:11], y2[:11])  # y[k] for k <= 10 cannot see u[10]
    assert abs(y2[11] - y0[11]) > 10.0  # y[11] responds to u[10]


def test_settling_forgets_the_initial_state() -> None:
    u = np.random.default_rng(2).uniform(0.007, 0.015, 40)
    a = reactor_output(reactor_states(u, reactor_steady_state(0.007)))
    b = reactor_output(reactor_states(u, reactor_steady_state(0.015)))
    assert abs(a[0] - b[0]) > 1000.0
    assert np.max(np.abs(a[25:] / b[25:] - 1.0)) < 1e-12  # default settle_samples = 25


def test_same_seed_same_output_and_global_rng_unused() -> None:
    np.random.seed(1)
    state = np.random.get_state()[1].copy()
    a = simulate_reactor(200, 42)
    np.random.seed(999)
    b = simulate_reactor(200, np.random.default_rng(42))
    assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    np.random.seed(1)
    simulate_reactor(50, 5)
    assert np.array_equal(np.random.get_state()[1], state)
    c = simulate_reactor(200, 43)
    assert not np.array_equal(a.y, c.y)


@pytest.mark.parametrize(
    ("call", "needle"),
    [
        (lambda: simulate_reactor(0, 1), "n_samples"),
        (lambda: simulate_reactor(10, None), "Generator"),  # type: ignore[arg-type]
        (lambda: simulate_reactor(10, 1, settle_samples=-1), "settle_samples"),
        (lambda: simulate_reactor_input([0.01, -0.001]), "-0.001"),
        (lambda: simulate_reactor_input([0.01, np.nan]), "finite"),
        (lambda: ReactorParams(u_low=0.02, u_high=0.01), "u_low"),
    ],
)
def test_bad_arguments_raise_config_error(call, needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        call()
