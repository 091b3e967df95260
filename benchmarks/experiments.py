"""Two-experiment pairs from the simulators: a model estimated on one excitation, validated on *another*.

A model chosen by the record it was fitted on can fail on the next experiment (issue 37); these pairs are the
suite's test of that. Every pair estimates on one experiment and validates on a second one of the same simulated
device with another excitation type, spectrum or amplitude, from a fresh initial state and fresh measurement noise.
Each device has two pairs inside the estimation's amplitude range and one a step beyond it (``beyond``: the
validation's peak input about 25 % above the estimation's).

==============  =======  ====================================================  ===========================================
device          rate     estimation -> validation                              samples (est / val)
==============  =======  ====================================================  ===========================================
piezo           2 kHz    band-limited noise -> log sine sweep                  4000 / 4000 (simulated at 20 kHz, decimated
                         slow sines -> multisine of growing amplitude                        by 10 with a zero-phase FIR)
                         multisine 80 V -> multisine of growing amp. to 100 V
mr_damper       200 Hz   band-limited velocity -> log sine sweep               4000 / 4000
                         slow sines -> multisine of growing amplitude
                         multisine peak 20 cm/s -> growing to 25 cm/s     
bouc_wen        750 Hz   band-limited noise -> log sine sweep                  6000 / 6000
                         multisine 50 N RMS -> steps (random levels)
                         multisine 40 N RMS -> growing to 50 N RMS
reactor         5 Hz     i.i.d. uniform (the paper's) -> random steps           480 / 480
                         random steps -> slow sines
                         uniform in the inner 60 % -> uniform in the full range
==============  =======  ====================================================  ===========================================

Everything is seeded from fixed integers (the pairs are the same on every machine); the identification's seeds are
the suite's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Experiment", "PAIRS", "pair"]

Signal = NDArray[np.float64]


@dataclass(frozen=True)
class Experiment:
    """One estimation/validation pair of one simulated device: inputs ``(N, 1)``, outputs ``(N,)``."""

    system: str
    label: str
    u_est: Signal
    y_est: Signal
    u_val: Signal
    y_val: Signal
    beyond: bool = False


# --- excitations (pure functions of their arguments and a generator) ---------------------------------------------

def _band_noise(n: int, fs: float, band: tuple[float, float], rms: float, gen: np.random.Generator) -> Signal:
    """Random-phase multisine with flat amplitude on the DFT lines of ``band`` (periodic over ``n``), RMS ``rms``."""
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    lines = (freqs >= band[0]) & (freqs <= band[1]) & (freqs > 0) & (np.arange(freqs.size) < n / 2)
    spec = np.zeros(freqs.size, dtype=np.complex128)
    spec[lines] = np.exp(2j * np.pi * gen.random(int(lines.sum())))
    x = np.fft.irfft(spec, n)
    return np.asarray(x * (rms / np.sqrt(np.mean(x**2))), dtype=np.float64)


def _sweep(n: int, fs: float, f0: float, f1: float, amp: float) -> Signal:
    """Logarithmic sine sweep from ``f0`` to ``f1`` Hz, peak ``amp``."""
    t = np.arange(n) / fs
    k = np.log(f1 / f0) / t[-1]
    return np.asarray(amp * np.sin(2 * np.pi * f0 * (np.exp(k * t) - 1.0) / k), dtype=np.float64)


def _slow_sines(n: int, fs: float, freqs: tuple[float, ...], amp: float) -> Signal:
    """A sum of sines of equal amplitude at ``freqs`` Hz, scaled to peak ``amp``."""
    t = np.arange(n) / fs
    x = sum(np.sin(2 * np.pi * f * t + 0.7 * i) for i, f in enumerate(freqs))
    return np.asarray(amp * x / np.max(np.abs(x)), dtype=np.float64)


def _growing(x: Signal, start: float = 0.15) -> Signal:
    """``x`` under an envelope rising linearly from ``start`` to 1."""
    return np.asarray(x * np.linspace(start, 1.0, x.size), dtype=np.float64)


def _steps(n: int, hold: tuple[int, int], lo: float, hi: float, gen: np.random.Generator) -> Signal:
    """Random levels in ``[lo, hi]``, each held a random ``hold[0]..hold[1]`` samples."""
    out = np.empty(n)
    i = 0
    while i < n:
        k = int(gen.integers(hold[0], hold[1] + 1))
        out[i : i + k] = gen.uniform(lo, hi)
        i += k
    return out


def _peak(x: Signal, amp: float) -> Signal:
    return np.asarray(x * (amp / np.max(np.abs(x))), dtype=np.float64)


def _taper(x: Signal, frac: float = 0.05) -> Signal:
    """Both ends brought smoothly to zero (a Tukey window): a signal the MR damper's periodic simulation can take."""
    from scipy.signal.windows import tukey

    return np.asarray(x * tukey(x.size, 2 * frac), dtype=np.float64)


# --- devices ---------------------------------------------------------------------------------------------------

_PIEZO_DECIMATE = 10  # 20 kHz -> 2 kHz


def _piezo(u_2k: Signal, seed: int) -> tuple[Signal, Signal]:
    """The simulated piezo at 20 kHz driven by ``u_2k`` (held), its output decimated back to 2 kHz."""
    from scipy.signal import decimate

    from streamid.sim import simulate_piezo_input

    u20 = np.repeat(u_2k, _PIEZO_DECIMATE)
    tr = simulate_piezo_input(u20, seed)
    y = decimate(np.asarray(tr.y), _PIEZO_DECIMATE, ftype="fir", zero_phase=True)
    return u_2k, np.asarray(y, dtype=np.float64)


def _mr(v: Signal, seed: int) -> tuple[Signal, Signal]:
    """The simulated MR damper (200 Hz) for the velocity ``v`` (cm/s, tapered: periodic over the record)."""
    from streamid.sim.mrdamper import MRDamperParams, mr_damper_force

    p = MRDamperParams()
    n = v.size
    v_spec = np.fft.rfft(v)
    v_spec[0] = 0.0
    freqs = np.fft.rfftfreq(n, p.period_s)
    x_spec = np.zeros_like(v_spec)
    x_spec[1:] = v_spec[1:] / (2j * np.pi * freqs[1:])
    vel, force = mr_damper_force(v_spec, x_spec, n, p, settle_samples=200)
    force = force + np.random.default_rng(seed).normal(0.0, p.noise_n, size=n)
    return np.asarray(vel, dtype=np.float64), np.asarray(force, dtype=np.float64)


def _bw(u: Signal, seed: int) -> tuple[Signal, Signal]:
    """The Bouc-Wen benchmark oscillator (750 Hz) from rest; noiseless as the benchmark's own data."""
    from streamid.sim import simulate_bouc_wen

    return u, np.asarray(simulate_bouc_wen(u).y, dtype=np.float64)


def _reactor(u: Signal, seed: int) -> tuple[Signal, Signal]:
    """The paper's reactor (5 Hz) from its steady state at the mid input, 25 settling samples dropped."""
    from streamid.sim.reactor import ReactorParams, reactor_steady_state, simulate_reactor_input

    p = ReactorParams()
    mid = 0.5 * (p.u_low + p.u_high)
    settle = np.full(25, mid)
    tr = simulate_reactor_input(np.concatenate([settle, u]), reactor_steady_state(mid, p), p)
    return u, np.asarray(tr.y, dtype=np.float64)[25:]


def _experiment(system: str, label: str, sim: Callable[[Signal, int], tuple[Signal, Signal]], u_est: Signal,
                u_val: Signal, seed: int, beyond: bool = False) -> Experiment:
    ue, ye = sim(u_est, seed)
    uv, yv = sim(u_val, seed + 1)
    return Experiment(system, label, ue.reshape(-1, 1), ye, uv.reshape(-1, 1), yv, beyond)


def _piezo_pairs() -> list[Experiment]:
    fs, n = 2000.0, 4000
    g = np.random.default_rng(101)
    return [
        _experiment("piezo_sim", "noise->sweep", _piezo, _peak(_band_noise(n, fs, (0.5, 200.0), 1.0, g), 100.0),
                    _sweep(n, fs, 1.0, 150.0, 90.0), 11),
        _experiment("piezo_sim", "sines->growing multisine", _piezo, _slow_sines(n, fs, (1.5, 4.0, 9.5), 100.0),
                    _peak(_growing(_band_noise(n, fs, (0.5, 60.0), 1.0, g)), 95.0), 13),
        _experiment("piezo_sim", "multisine 80 V->100 V", _piezo, _peak(_band_noise(n, fs, (0.5, 100.0), 1.0, g), 80.0),
                    _peak(_growing(_band_noise(n, fs, (0.5, 100.0), 1.0, g), 0.5), 100.0), 15, beyond=True),
    ]


def _mr_pairs() -> list[Experiment]:
    fs, n = 200.0, 4000
    g = np.random.default_rng(202)
    return [
        _experiment("mr_damper_sim", "noise->sweep", _mr, _taper(_band_noise(n, fs, (0.5, 10.0), 6.0, g)),
                    _taper(_sweep(n, fs, 0.5, 8.0, 12.0)), 21),
        _experiment("mr_damper_sim", "sines->growing multisine", _mr, _taper(_slow_sines(n, fs, (0.8, 2.1, 4.7), 15.0)),
                    _taper(_peak(_growing(_band_noise(n, fs, (0.5, 6.0), 1.0, g)), 13.0)), 23),
        _experiment("mr_damper_sim", "peak 20->25 cm/s", _mr, _taper(_peak(_band_noise(n, fs, (0.5, 10.0), 1.0, g), 20.0)),
                    _taper(_peak(_growing(_band_noise(n, fs, (0.5, 10.0), 1.0, g), 0.5), 25.0)), 25, beyond=True),
    ]


def _bw_pairs() -> list[Experiment]:
    fs, n = 750.0, 6000
    g = np.random.default_rng(303)
    return [
        _experiment("bouc_wen_sim", "noise->sweep", _bw, _band_noise(n, fs, (5.0, 150.0), 50.0, g),
                    _sweep(n, fs, 10.0, 80.0, 60.0), 31),
        _experiment("bouc_wen_sim", "multisine->steps", _bw, _band_noise(n, fs, (5.0, 150.0), 50.0, g),
                    _steps(n, (40, 200), -80.0, 80.0, g), 33),
        _experiment("bouc_wen_sim", "peak 150->190 N", _bw, _peak(_band_noise(n, fs, (5.0, 150.0), 1.0, g), 150.0),
                    _peak(_growing(_band_noise(n, fs, (5.0, 150.0), 1.0, g), 0.5), 190.0), 35, beyond=True),
    ]


def _reactor_pairs() -> list[Experiment]:
    from streamid.sim.reactor import ReactorParams

    p = ReactorParams()
    lo, hi, n = p.u_low, p.u_high, 480
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    g = np.random.default_rng(404)
    return [
        _experiment("reactor_sim", "uniform->steps", _reactor, g.uniform(lo, hi, n), _steps(n, (10, 40), lo, hi, g), 41),
        _experiment("reactor_sim", "steps->sines", _reactor, _steps(n, (10, 40), lo, hi, g),
                    mid + _slow_sines(n, 5.0, (0.011, 0.037, 0.083), 0.95 * half), 43),
        _experiment("reactor_sim", "inner 60 %->full range", _reactor, g.uniform(mid - 0.6 * half, mid + 0.6 * half, n),
                    g.uniform(lo, hi, n), 45, beyond=True),
    ]


#: device -> its pairs (built on demand: the piezo's and the damper's simulations take a few seconds).
PAIRS: dict[str, Callable[[], list[Experiment]]] = {
    "piezo_sim": _piezo_pairs,
    "mr_damper_sim": _mr_pairs,
    "bouc_wen_sim": _bw_pairs,
    "reactor_sim": _reactor_pairs,
}


def pair(system: str) -> list[Experiment]:
    """The pairs of one simulated device (:data:`PAIRS`)."""
    return PAIRS[system]()
