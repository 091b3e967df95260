r"""Continuous polymerization reactor of the paper (eq. 17), sampled at 5 Hz.

Free-radical polymerization of methyl methacrylate (MMA) with AIBN as initiator
and toluene as solvent in a jacketed continuous stirred tank reactor. The
first-principles state-space model, as written in eq. (17) of the method paper
(its ref. [43]; the model is commonly quoted from Doyle, Ogunnaike & Pearson,
Automatica 1995), with every variable dimensionless and the time unit taken as
1 s so that the paper's 5 Hz sampling is ``T = 0.2``::

    dz1/dt = 10 (6 - z1) - 2.4568 sqrt(z2)                 (17a) monomer concentration
    dz2/dt = 80 u - 10.1022 z2                             (17b) initiator concentration
    dz3/dt = 0.0024121 z1 sqrt(z2) + 0.112191 z2 - 10 z3   (17c)
    dz4/dt = 245.978 z1 sqrt(z2) - 10 z4                   (17d)
    y      = z4 / z3                                       (17e) number-average molecular weight

``u`` is the dimensionless volumetric flow rate of the initiator, drawn i.i.d.
``u ~ U[0.007, 0.015]`` (the paper's ref. [44]); the paper states that ``y``
then stays roughly within 2.6e4 .. 3.4e4. Exactly, every output lies between
the fixed points of the extreme inputs, ``y*(0.015) = 27 487`` and
``y*(0.007) = 35 871`` (a 960-sample record spans ~2.78e4 .. 3.52e4; 50 000
samples 2.755e4 .. 3.564e4), so the paper's range is a rounded description.

Sampling and indexing convention
--------------------------------
Sample ``k`` is at ``t_k = k T`` with ``T = 0.2`` (5 Hz; ``period_ns =
200_000_000``). The input is a zero-order hold: ``u[k]`` is applied over
``[t_k, t_{k+1})``. The output ``y[k] = z4(t_k) / z3(t_k)`` is measured at
``t_k`` *before* ``u[k]`` has had any effect, so ``y[k]`` depends on
``u[k-1], u[k-2], ...`` and on no later input: exactly the NARX form
``y(t) = F[y(t-1), ..., u(t-1), u(t-2), ...]``. (The paper and ref. [44] find
``y(t-1), u(t-1), u(t-2)`` sufficient.)

Integration (exact up to quadrature, vectorised over samples)
-------------------------------------------------------------
Every state decays linearly at its own rate and is driven by a forcing that
depends only on states *earlier* in the chain ``z2 -> z1 -> (z3, z4)``, so each
is solved with the variation-of-constants formula over one hold interval
``s in [0, T]``::

    z2(t_k+s) = w_k + (z2_k - w_k) exp(-10.1022 s),         w_k = 80 u_k / 10.1022   (exact)
    x(t_k+s)  = exp(-a s) x_k + int_0^s exp(-a (s-r)) f(r) dr   for x in z1, z3, z4

The convolution integrals are evaluated by Gauss-Legendre quadrature (default
8 nodes; the integrands are analytic on the interval because ``z2 > 0``, so the
error is at round-off level, ~1e-12 relative, checked against
``scipy.integrate.solve_ivp(method="DOP853", rtol=1e-12)`` in the tests). The
values of ``z1`` needed inside the interval for the ``z3``/``z4`` forcings come
from a nested quadrature. The resulting per-sample affine recurrences
``x_{k+1} = exp(-a T) x_k + b_k`` are run with :func:`scipy.signal.lfilter`,
so there is no Python loop over samples: 960 samples (plus 25 settling)
take 1.6 ms on the project machine (min of 20).

Initial state and settling
--------------------------
The simulation starts at the analytical fixed point for the mean input
``u = 0.011`` (:func:`reactor_steady_state`) and runs ``settle_samples`` extra
random-input samples which are discarded, so the returned record is a
stationary response. All modes decay with rates ~10 per time unit (time
constant 0.1, i.e. half a sample), so the default 25 settling samples
(5 time units, ``exp(-50)``) leave no trace of the initial state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from streamid.errors import ConfigError
from streamid.sim._common import (
    Trace,
    as_generator,
    as_signal,
    check_nonneg_int,
    check_positive_int,
    sample_times_ns,
)

__all__ = [
    "ReactorParams",
    "reactor_steady_state",
    "reactor_states",
    "reactor_output",
    "simulate_reactor",
    "simulate_reactor_input",
]


@dataclass(frozen=True)
class ReactorParams:
    """Coefficients of eq. (17) and the excitation of the paper.

    The defaults are the published values; every coefficient is named after
    its place in ``dz/dt`` (see the module docstring).

    Attributes
    ----------
    k1 : float
        Dilution rate in (17a): ``dz1 = k1 (z1_feed - z1) - c1 sqrt(z2)``. 10.
    z1_feed : float
        Feed monomer concentration in (17a). 6.
    c1 : float
        Monomer consumption coefficient in (17a). 2.4568.
    b2 : float
        Input gain in (17b): ``dz2 = b2 u - a2 z2``. 80.
    a2 : float
        Initiator decay rate in (17b). 10.1022.
    c31, c32 : float
        Coefficients of (17c): ``dz3 = c31 z1 sqrt(z2) + c32 z2 - a3 z3``. 0.0024121, 0.112191.
    a3 : float
        Decay rate in (17c). 10.
    c4 : float
        Coefficient of (17d): ``dz4 = c4 z1 sqrt(z2) - a4 z4``. 245.978.
    a4 : float
        Decay rate in (17d). 10.
    u_low, u_high : float
        Bounds of the uniform input, ``U[0.007, 0.015]``.
    period_ns : int
        Sample period, 200_000_000 ns (5 Hz); the model's time unit is 1 s here.
    n_gauss : int
        Gauss-Legendre nodes per hold interval (accuracy of the quadrature). 8.
    """

    k1: float = 10.0
    z1_feed: float = 6.0
    c1: float = 2.4568
    b2: float = 80.0
    a2: float = 10.1022
    c31: float = 0.0024121
    c32: float = 0.112191
    a3: float = 10.0
    c4: float = 245.978
    a4: float = 10.0
    u_low: float = 0.007
    u_high: float = 0.015
    period_ns: int = 200_000_000
    n_gauss: int = 8

    def __post_init__(self) -> None:
        for name in ("k1", "a2", "a3", "a4", "b2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"ReactorParams.{name} must be a finite number > 0; got {v!r}")
        if not (0.0 < self.u_low < self.u_high and np.isfinite(self.u_high)):
            raise ConfigError(
                "ReactorParams input bounds must satisfy 0 < u_low < u_high < inf; "
                f"got u_low={self.u_low!r}, u_high={self.u_high!r}"
            )
        check_positive_int("ReactorParams.period_ns", self.period_ns)
        check_positive_int("ReactorParams.n_gauss", self.n_gauss)

    @property
    def period_s(self) -> float:
        """Sample period in seconds (model time units)."""
        return self.period_ns * 1e-9

    @property
    def u_mean(self) -> float:
        """Mean of the uniform input, the operating point (0.011)."""
        return 0.5 * (self.u_low + self.u_high)


def reactor_steady_state(u: float, params: ReactorParams = ReactorParams()) -> NDArray[np.float64]:
    """Analytical fixed point ``z*`` of eq. (17) for a constant input ``u``.

    Setting the derivatives to zero::

        z2* = b2 u / a2
        z1* = z1_feed - c1 sqrt(z2*) / k1
        z3* = (c31 z1* sqrt(z2*) + c32 z2*) / a3
        z4* = c4 z1* sqrt(z2*) / a4

    Parameters
    ----------
    u : float
        Constant input, >= 0.
    params : ReactorParams

    Returns
    -------
    ndarray, shape (4,)
        ``[z1*, z2*, z3*, z4*]``; the output is ``z4* / z3*``.
    """
    if not (np.isfinite(u) and u >= 0):
        raise ConfigError(f"reactor input must be a finite number >= 0; got {u!r}")
    p = params
    z2 = p.b2 * u / p.a2
    q = np.sqrt(z2)
    z1 = p.z1_feed - p.c1 * q / p.k1
    z3 = (p.c31 * z1 * q + p.c32 * z2) / p.a3
    z4 = p.c4 * z1 * q / p.a4
    return np.array([z1, z2, z3, z4], dtype=np.float64)


def _affine_recurrence(decay: float, x0: float, forcing: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return ``x[0..N]`` with ``x[0] = x0`` and ``x[k+1] = decay * x[k] + forcing[k]``."""
    from scipy.signal import lfilter  # scipy.signal costs 0.8 s to import: only a simulation pays it

    out = np.empty(forcing.size + 1)
    out[0] = x0
    out[1:] = lfilter([1.0], [1.0, -decay], forcing, zi=[decay * x0])[0]
    return out


def reactor_states(
    u: NDArray[np.float64] | list[float],
    z0: NDArray[np.float64] | None = None,
    params: ReactorParams = ReactorParams(),
) -> NDArray[np.float64]:
    """States at the sample instants for a zero-order-held input sequence.

    Parameters
    ----------
    u : array_like, shape (N,)
        Input, ``u[k]`` held over ``[t_k, t_{k+1})``; must be >= 0 (a flow rate).
    z0 : array_like, shape (4,), optional
        State at ``t_0``; default the fixed point for ``params.u_mean``.
    params : ReactorParams

    Returns
    -------
    ndarray, shape (N + 1, 4)
        ``z[k] = z(t_k)`` for ``k = 0..N`` (row ``N`` is the state after the last input).
    """
    p = params
    u_arr = as_signal("reactor input u", u)
    if np.any(u_arr < 0):
        bad = int(np.flatnonzero(u_arr < 0)[0])
        raise ConfigError(
            f"reactor input u is a flow rate and must be >= 0; got {u_arr[bad]!r} at index {bad}"
        )
    z_init = reactor_steady_state(p.u_mean, p) if z0 is None else np.asarray(z0, dtype=np.float64)
    if z_init.shape != (4,) or not np.all(np.isfinite(z_init)) or z_init[1] < 0:
        raise ConfigError(f"reactor initial state z0 must be 4 finite numbers with z2 >= 0; got {z0!r}")

    T = p.period_s
    x, w = np.polynomial.legendre.leggauss(p.n_gauss)
    x = 0.5 * (x + 1.0)  # nodes on [0, 1]
    w = 0.5 * w  # weights on [0, 1]
    s = T * x  # outer nodes in the interval, (J,)
    r = s[:, None] * x[None, :]  # inner nodes on [0, s_j], (J, I)

    # z2: exact solution of the linear ODE under zero-order hold.
    e2 = np.exp(-p.a2 * T)
    w_ss = p.b2 * u_arr / p.a2  # fixed point for each held input, (N,)
    z2 = _affine_recurrence(e2, float(z_init[1]), (1.0 - e2) * w_ss)
    dz2 = (z2[:-1] - w_ss)[:, None]  # (N, 1)
    z2_s = w_ss[:, None] + dz2 * np.exp(-p.a2 * s)[None, :]  # (N, J)
    z2_r = w_ss[:, None, None] + dz2[:, :, None] * np.exp(-p.a2 * r)[None, :, :]  # (N, J, I)
    q_s = np.sqrt(z2_s)
    q_r = np.sqrt(z2_r)

    # z1: forcing g1 = k1 z1_feed - c1 sqrt(z2), decay k1.
    g1_s = p.k1 * p.z1_feed - p.c1 * q_s
    g1_r = p.k1 * p.z1_feed - p.c1 * q_r
    kern_T1 = T * w * np.exp(-p.k1 * (T - s))  # (J,)
    z1 = _affine_recurrence(np.exp(-p.k1 * T), float(z_init[0]), g1_s @ kern_T1)
    kern_s1 = s[:, None] * w[None, :] * np.exp(-p.k1 * (s[:, None] - r))  # (J, I)
    z1_s = z1[:-1, None] * np.exp(-p.k1 * s)[None, :] + np.einsum("nji,ji->nj", g1_r, kern_s1)

    # z3, z4: forcings from z1 and z2 inside the interval.
    zq = z1_s * q_s
    f3 = p.c31 * zq + p.c32 * z2_s
    f4 = p.c4 * zq
    z3 = _affine_recurrence(np.exp(-p.a3 * T), float(z_init[2]), f3 @ (T * w * np.exp(-p.a3 * (T - s))))
    z4 = _affine_recurrence(np.exp(-p.a4 * T), float(z_init[3]), f4 @ (T * w * np.exp(-p.a4 * (T - s))))
    return np.stack([z1, z2, z3, z4], axis=1)


def reactor_output(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Number-average molecular weight ``y = z4 / z3`` (eq. 17e) for states of shape (..., 4)."""
    z = np.asarray(z, dtype=np.float64)
    return z[..., 3] / z[..., 2]


def simulate_reactor_input(
    u: NDArray[np.float64] | list[float],
    z0: NDArray[np.float64] | None = None,
    params: ReactorParams = ReactorParams(),
) -> Trace:
    """Deterministic response to a given input (no settling, no noise).

    Parameters
    ----------
    u : array_like, shape (N,)
        Input, ``u[k]`` held over ``[t_k, t_{k+1})``.
    z0 : array_like, shape (4,), optional
        State at ``t_0``; default the fixed point for ``params.u_mean``.
    params : ReactorParams

    Returns
    -------
    Trace
        ``(t_ns, u, y)`` with ``y[k] = z4(t_k)/z3(t_k)`` (depends on ``u[:k]`` only).
    """
    z = reactor_states(u, z0, params)
    u_arr = np.asarray(u, dtype=np.float64)
    return Trace(sample_times_ns(u_arr.size, params.period_ns), u_arr.copy(), reactor_output(z[:-1]))


def simulate_reactor(
    n_samples: int,
    rng: np.random.Generator | int,
    *,
    settle_samples: int = 25,
    params: ReactorParams = ReactorParams(),
) -> Trace:
    """Simulate the reactor at 5 Hz with i.i.d. uniform input, as in the paper.

    Draws ``settle_samples + n_samples`` inputs ``u ~ U[u_low, u_high]`` from
    ``rng`` (in one call, settling inputs first), integrates eq. (17) from the
    fixed point of the mean input, and returns the last ``n_samples``.

    Parameters
    ----------
    n_samples : int
        Number of samples returned (the paper uses 960: 480 estimation + 480 validation).
    rng : numpy.random.Generator or int
        Source of the input draws (or a seed for one).
    settle_samples : int, default 25
        Leading samples simulated and discarded (5 s = 50 time constants).
    params : ReactorParams

    Returns
    -------
    Trace
        ``t_ns`` (``k * 200_000_000``, starting at 0 after settling), ``u``
        (dimensionless initiator flow rate), ``y`` (number-average molecular
        weight, ~2.6e4 .. 3.4e4). ``y[k]`` is measured at ``t_k`` and depends on
        ``u[k-1], u[k-2], ...`` (and on settling inputs for the first samples).

    Examples
    --------
    >>> import numpy as np
    >>> t_ns, u, y = simulate_reactor(960, np.random.default_rng(0))
    >>> t_ns[1] - t_ns[0]
    np.int64(200000000)
    """
    n = check_positive_int("n_samples", n_samples)
    n_settle = check_nonneg_int("settle_samples", settle_samples)
    gen = as_generator(rng)
    u_all = gen.uniform(params.u_low, params.u_high, size=n_settle + n)
    y_all = reactor_output(reactor_states(u_all, None, params)[:-1])
    return Trace(sample_times_ns(n, params.period_ns), u_all[n_settle:], y_all[n_settle:])
