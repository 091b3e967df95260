r"""Piezoelectric unimorph micromanipulator at 20 kHz: Bouc-Wen hysteresis + cantilever dynamics.

The device of the paper's third case study: a free-clamped PZT/copper unimorph
cantilever (15 mm x 2 mm x 0.3 mm; PZT 0.2 mm, Cu 0.1 mm), voltage ``u`` in,
tip deflection ``y`` out, measured by an optical sensor (Keyence LK-2420 tuned
to 40 nm resolution and 5 kHz bandwidth), sampled every 50 us by a dSPACE
board whose DAC holds ``u`` between samples.

Model
-----
Classical Bouc-Wen hysteresis in series with second-order structural
dynamics, the model family used for this very kind of actuator by Rakotondrabe
(IEEE T-ASE 8(2), 2011, "Bouc-Wen modeling and inverse multiplicative structure
to compensate hysteresis nonlinearity in piezoelectric actuators") and, for
stacks, by Low & Guo (IEEE/ASME J. MEMS 4(4), 1995)::

    h' = A d_p u' - B |u'| h - G u' |h|                 hysteresis   [um/s]
    w  = d_p u - h                                      quasi-static deflection [um]
    y'' + 2 zeta wn y' + wn^2 y = wn^2 w                cantilever's first bending mode [um]
    y_m = S(y) + e,  e ~ N(0, noise_um^2)               sensor: 2nd-order 5 kHz low-pass S, noise

``h`` is rate independent (it depends on the path of ``u`` only), so with the
DAC's zero-order hold it is computed *exactly* at the samples by
:func:`streamid.sim.boucwen.bouc_wen_operator`; ``w`` is then piecewise
constant and the mode is discretised exactly (zero-order hold,
:func:`scipy.signal.cont2discrete`) and run with :func:`scipy.signal.lfilter`.
The sensor low-pass is a digital Butterworth filter at ``sensor_bandwidth_hz``.
Not modelled: creep, rate-dependent hysteresis, higher bending modes.

Parameters and their sources (our choices, physically plausible, not identified values)
-----------------------------------------------------------------------------------------
- ``d_p = 0.33 um/V``: Timoshenko bilayer curvature for the paper's geometry with
  PZT-5A-like ``d31 = -190 pm/V``, ``E_PZT = 63 GPa``, ``E_Cu = 117 GPa`` and a
  12 mm free length (3 mm in the clamp) gives 33 um at 100 V.
- ``wn = 2 pi 1.0 kHz``: Euler-Bernoulli first mode ``(1.8751^2 / 2 pi) sqrt(EI / rho A) / L^2``
  of the same composite (rho 7750 / 8960 kg/m^3) is 0.69 kHz at 15 mm and 1.08 kHz at
  12 mm free length; we take 1.0 kHz. ``zeta = 0.03``: lightly damped cantilever
  in air (Rakotondrabe et al. report strongly oscillating step responses).
- ``A = 0.3, B = 0.008 1/V, G = 0.004 1/V``: at 1 Hz the loop's width at 0 V is
  12 % of the stroke (52.6 um peak to peak) for +-100 V and 5 % for +-30 V, as
  typical of PZT (10-20 % at full stroke); ``B > |G|`` gives the usual
  non-saturating loop. Small-signal gain ``d_p (1 - A)``.
- Sensor: 40 nm noise standard deviation and 5 kHz bandwidth (the paper's
  Keyence settings).

Excitation
----------
``u = c (e(t) m_lo(t) + r m_hi(t))`` scaled to a peak of ``amplitude_v`` (100 V):
``m_lo`` a random-phase multisine on 0.5-20 Hz (large quasi-static loops with
many minor loops: the hysteresis), ``e`` a slow random envelope (0.05-0.5 Hz)
in [0.2, 1] that varies the loop amplitude, and ``m_hi`` a random-phase
multisine on 20 Hz-3 kHz with ``r = 0.08`` of the low band's RMS that excites
the 1 kHz mode (the dynamics). The record fades in from 0 V (virgin
hysteresis state) over ``settle_s`` seconds that are discarded.

Indexing: ``u[k]`` is held over ``[t_k, t_{k+1})`` and ``y[k]`` is measured at
``t_k``; the structural response to ``u[k]`` appears from ``y[k+1]`` on.
Speed: 60 s at 20 kHz (1.2 M samples) take 0.51 s on the project machine,
dominated by the scalar hysteresis loop (~0.35 us per sample).
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
    check_positive_float,
    check_positive_int,
    sample_times_ns,
)
from streamid.sim.boucwen import bouc_wen_operator

__all__ = ["PiezoParams", "piezo_excitation", "simulate_piezo", "simulate_piezo_input"]


@dataclass(frozen=True)
class PiezoParams:
    """Physical and sensor parameters of the unimorph (see the module docstring for sources).

    Attributes
    ----------
    d_p : float
        Piezoelectric gain, um/V (0.33).
    hyst_a : float
        Bouc-Wen ``A``, dimensionless (0.3).
    hyst_b : float
        Bouc-Wen ``B``, 1/V (0.008).
    hyst_g : float
        Bouc-Wen ``Gamma``, 1/V (0.004).
    resonance_hz : float
        Undamped natural frequency of the first bending mode, Hz (1000).
    zeta : float
        Damping ratio of the mode (0.03).
    sensor_bandwidth_hz : float or None
        Cut-off of the sensor's 2nd-order Butterworth low-pass, Hz (5000); None: ideal sensor.
    noise_um : float
        Standard deviation of the white measurement noise, um (0.04).
    period_ns : int
        Sample period, ns (50_000: 20 kHz).
    """

    d_p: float = 0.33
    hyst_a: float = 0.3
    hyst_b: float = 0.008
    hyst_g: float = 0.004
    resonance_hz: float = 1000.0
    zeta: float = 0.03
    sensor_bandwidth_hz: float | None = 5000.0
    noise_um: float = 0.04
    period_ns: int = 50_000

    def __post_init__(self) -> None:
        check_positive_float("PiezoParams.d_p", self.d_p)
        check_positive_float("PiezoParams.resonance_hz", self.resonance_hz)
        check_positive_float("PiezoParams.zeta", self.zeta)
        check_positive_int("PiezoParams.period_ns", self.period_ns)
        for name in ("hyst_a", "hyst_b", "hyst_g", "noise_um"):
            v = getattr(self, name)
            if not np.isfinite(v):
                raise ConfigError(f"PiezoParams.{name} must be a finite number; got {v!r}")
        if self.hyst_a < 0 or self.hyst_b < 0 or self.noise_um < 0:
            raise ConfigError(
                "PiezoParams.hyst_a, .hyst_b and .noise_um must be >= 0; got "
                f"{self.hyst_a!r}, {self.hyst_b!r}, {self.noise_um!r}"
            )
        nyquist = 0.5e9 / self.period_ns
        if self.sensor_bandwidth_hz is not None and not (0 < self.sensor_bandwidth_hz < nyquist):
            raise ConfigError(
                f"PiezoParams.sensor_bandwidth_hz must be in (0, {nyquist:g}) Hz (Nyquist) or None; "
                f"got {self.sensor_bandwidth_hz!r}"
            )

    @property
    def period_s(self) -> float:
        """Sample period in s."""
        return self.period_ns * 1e-9


def _mode_filter(p: PiezoParams) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact ZOH discretisation of ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` as lfilter (b, a)."""
    from scipy.signal import cont2discrete  # scipy.signal costs 0.8 s to import: only a simulation pays it
    wn = 2.0 * np.pi * p.resonance_hz
    num, den, _ = cont2discrete(([wn**2], [1.0, 2.0 * p.zeta * wn, wn**2]), p.period_s, method="zoh")
    return np.asarray(num, dtype=np.float64).ravel(), np.asarray(den, dtype=np.float64).ravel()


def _piezo_clean(u: NDArray[np.float64], p: PiezoParams) -> NDArray[np.float64]:
    """Noise-free sensor output for a held voltage sequence starting at rest (u = 0 V before t_0)."""
    from scipy.signal import butter, lfilter

    u_ext = np.concatenate([[0.0], u])  # virgin state at 0 V before the first sample
    h = bouc_wen_operator(
        u_ext, alpha=p.hyst_a * p.d_p, beta=1.0, gamma=p.hyst_b, delta=p.hyst_g, nu=1.0
    )[1:]
    w = p.d_p * u - h
    b, a = _mode_filter(p)
    y = lfilter(b, a, w)  # b[0] == 0: y[k] depends on w[k-1] and earlier
    if p.sensor_bandwidth_hz is not None:
        sb, sa = butter(2, p.sensor_bandwidth_hz, fs=1.0 / p.period_s)
        y = lfilter(sb, sa, y)
    return y


def simulate_piezo_input(
    u: NDArray[np.float64] | list[float],
    rng: np.random.Generator | int | None = None,
    *,
    params: PiezoParams = PiezoParams(),
) -> Trace:
    """Response of the actuator at rest (0 V, virgin hysteresis) to a given voltage sequence.

    Parameters
    ----------
    u : array_like, shape (N,)
        Voltage in V, held over each 50 us sample.
    rng : numpy.random.Generator or int, optional
        Source of the measurement noise; None gives the noise-free output.
    params : PiezoParams

    Returns
    -------
    Trace
        ``(t_ns, u [V], y [um])``.
    """
    u_arr = as_signal("piezo voltage u", u)
    y = _piezo_clean(u_arr, params)
    if rng is not None and params.noise_um > 0:
        y = y + as_generator(rng).normal(0.0, params.noise_um, size=y.size)
    return Trace(sample_times_ns(u_arr.size, params.period_ns), u_arr.copy(), y)


def _band_noise(n: int, fs: float, f_lo: float, f_hi: float, gen: np.random.Generator) -> NDArray[np.float64]:
    """Unit-RMS random-phase multisine on the DFT lines of ``[f_lo, f_hi]`` Hz, periodic over ``n``."""
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    band = (freqs >= f_lo) & (freqs <= f_hi) & (freqs > 0)
    if not np.any(band):
        raise ConfigError(
            f"a {n}-sample record at {fs:g} Hz has no frequency line in [{f_lo:g}, {f_hi:g}] Hz; "
            "accepted: a longer record"
        )
    spec = np.zeros(freqs.size, dtype=np.complex128)
    spec[band] = np.exp(2j * np.pi * gen.random(int(band.sum())))
    x = np.fft.irfft(spec, n)
    return x / np.sqrt(np.mean(x**2))


def piezo_excitation(
    n_samples: int,
    rng: np.random.Generator | int,
    *,
    amplitude_v: float = 100.0,
    period_ns: int = 50_000,
    lo_band_hz: tuple[float, float] = (0.5, 20.0),
    hi_band_hz: tuple[float, float] = (20.0, 3000.0),
    envelope_band_hz: tuple[float, float] = (0.05, 0.5),
    hi_ratio: float = 0.08,
) -> NDArray[np.float64]:
    """Amplitude-modulated two-band random-phase multisine (see the module docstring).

    Parameters
    ----------
    n_samples : int
        Length (the multisines are periodic over it; >= 2 s so that the low band has lines).
    rng : numpy.random.Generator or int
    amplitude_v : float
        Peak voltage, V (the paper's amplifier allows +-200 V).
    period_ns : int
        Sample period, ns.
    lo_band_hz, hi_band_hz, envelope_band_hz : (float, float)
        Bands of the hysteresis-exciting, dynamics-exciting and envelope multisines, Hz.
    hi_ratio : float
        RMS of the high band relative to the (modulated) low band.

    Returns
    -------
    ndarray, shape (n_samples,)
        Voltage in V with ``max |u| = amplitude_v``.
    """
    n = check_positive_int("n_samples", n_samples)
    amp = check_positive_float("amplitude_v", amplitude_v)
    fs = 1e9 / check_positive_int("period_ns", period_ns)
    gen = as_generator(rng)
    lo = _band_noise(n, fs, *lo_band_hz, gen)
    hi = _band_noise(n, fs, *hi_band_hz, gen)
    env_raw = _band_noise(n, fs, *envelope_band_hz, gen) if n / fs >= 1.0 / envelope_band_hz[0] else np.zeros(n)
    span = np.ptp(env_raw)
    env = 0.2 + 0.8 * (env_raw - env_raw.min()) / span if span > 0 else np.ones(n)
    x = env * lo
    x = x / np.sqrt(np.mean(x**2)) + hi_ratio * hi
    return x * (amp / np.max(np.abs(x)))


def simulate_piezo(
    n_samples: int,
    rng: np.random.Generator | int,
    *,
    params: PiezoParams = PiezoParams(),
    amplitude_v: float = 100.0,
    settle_s: float = 0.2,
) -> Trace:
    """Simulated identification experiment on the micromanipulator at 20 kHz.

    Draws the excitation (:func:`piezo_excitation` over ``settle + n_samples``
    samples), fades its first ``settle_s`` seconds in from 0 V with a raised
    cosine, simulates from rest, adds sensor noise, and returns the last
    ``n_samples``.

    Parameters
    ----------
    n_samples : int
        Samples returned (60 s at 20 kHz = 1 200 000).
    rng : numpy.random.Generator or int
        Draws the excitation, then the noise.
    params : PiezoParams
    amplitude_v : float
        Peak voltage, V.
    settle_s : float
        Fade-in, simulated and discarded, s.

    Returns
    -------
    Trace
        ``(t_ns, u [V], y [um])``.
    """
    n = check_positive_int("n_samples", n_samples)
    n_settle = check_nonneg_int("settle samples", int(round(max(settle_s, 0.0) / params.period_s)))
    gen = as_generator(rng)
    total = n + n_settle
    u = piezo_excitation(total, gen, amplitude_v=amplitude_v, period_ns=params.period_ns)
    if n_settle:
        u[:n_settle] *= 0.5 - 0.5 * np.cos(np.pi * np.arange(n_settle) / n_settle)
    y = _piezo_clean(u, params)
    if params.noise_um > 0:
        y = y + gen.normal(0.0, params.noise_um, size=total)
    return Trace(sample_times_ns(n, params.period_ns), u[n_settle:].copy(), y[n_settle:].copy())
