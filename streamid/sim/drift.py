r"""Simulated devices whose physics drifts at a known time: the ground truth of drift detection.

``simulate_drift(device, seconds, drift_at_s, change, rng)`` simulates the
device exactly as its registry simulator does (same excitation, same noise,
same integrator, same seed use) but multiplies the parameters that set its
output level by ``(1 + change)`` from the first sample at or after
``drift_at_s`` on. The state is carried across the change: the ODE/operator
is not restarted and the input is the undrifted record's input, sample for
sample. So before the change the output equals the undrifted simulation
*exactly* (bit for bit, tested), and after it the output follows the changed
device from the state the old one left.

==========  =============================  ==================================================
device      parameters scaled              first output sample that can differ
==========  =============================  ==================================================
mr_damper   alpha_a, alpha_b, c0a, c0b     ``k`` (the force responds to the state at ``t_k``)
piezo       d_p                            ``k + 1`` (``u[k]`` reaches the mode after one sample)
==========  =============================  ==================================================

where ``k = ceil(drift_at_ns / period_ns)``, ``drift_at_ns = round(drift_at_s * 1e9)``
(:func:`drift_start_ns` gives ``k * period_ns``).

Why these parameters, and why 20 % is realistic
-----------------------------------------------
*MR damper* (:mod:`.mrdamper`, Spencer et al. 1997). ``alpha`` (Bouc-Wen
scale: the field-dependent yield force) and ``c0`` (viscous damping at large
velocity) are the parameters that set the force level, and the two that
Spencer et al. make depend on the magnetic field (``alpha = alpha_a + alpha_b
u``, ``c0 = c0a + c0b u``). Scaling both ``a`` and ``b`` parts scales them at
every voltage. A 20 % change is what the two usual causes give:

- the field: at the simulated 1 V, ``alpha`` = 835 N/cm and 20 % of it is
  167 N/cm, i.e. 0.24 V of command (``alpha_b`` = 695 N/(cm V)); a coil driven
  by a voltage source loses current as it warms (copper's resistance rises
  0.39 %/K, so ~+50 K of coil temperature is ~-16 % current);
- the fluid: MR dampers self-heat while they stroke, and the carrier's
  viscosity (hence ``c0``) and the force fall with temperature (temperature
  tests of MR dampers span 0-100 degC for this reason, e.g. Sahin, Cesmeci &
  Wereley, "Sensitivity of magnetorheological damper behavior to perturbations
  in temperature via Bouc-Wen model").

``change = -0.2`` models heating (less force), ``+0.2`` cooling or a higher
current. ``c1`` (the low-velocity roll-off dashpot), the stiffnesses and the
Bouc-Wen shape are left alone, so the loop's shape is kept and its level moves.

*Piezo* (:mod:`.piezo`). ``d_p`` (the piezoelectric gain, um/V) scales the
quasi-static stroke and, through ``A d_p``, the hysteresis with it; the
bending mode and the sensor are unchanged. PZT's piezoelectric coefficients
change with temperature and with ageing or partial depoling of a hard-driven
actuator; 20 % is at the large end of that (a sizeable warm-up), chosen to
match the damper's case, not a measured value.

How much 20 % moves the output
------------------------------
``python -m streamid.sim.drift 0.2 -0.2`` (:func:`output_change`: noise-free, seeds 0-2; the
damper 60 s with the change at 30 s, the piezo 2 s with it at 1 s), after the change:

=========  ======  =========================================  ==========================================
device     change  RMS ratio (drifted / undrifted, about      RMS of the difference / undrifted RMS
                   the mean)
=========  ======  =========================================  ==========================================
mr_damper  +0.20   1.166-1.167                                0.171-0.172
mr_damper  -0.20   0.822-0.823                                0.181-0.182
mr_damper  +0.05   1.043                                      0.044
piezo      +-0.20  1.200 / 0.800                              0.200
=========  ======  =========================================  ==========================================

The damper's force moves by less than its parameters because ``c1``, ``k0``
and ``k1`` are unchanged (the force is ``c1 y' + k1 (x - x0)``, and ``y'`` is a
weighted mean in which ``alpha`` and ``c0`` are not the only terms); its 2 N
load-cell noise is 0.35 % of the force's 571 N standard deviation, so the
figures with noise are the same to 3 digits. The piezo is homogeneous in
``d_p`` (the Bouc-Wen state scales with ``A d_p``), so its change is a pure
gain of ``1 + change`` once the one-sample lag and the mode's ring-down pass.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from streamid.errors import ConfigError
from streamid.sim._common import Trace, as_generator, check_nonneg_int, check_positive_int, sample_times_ns
from streamid.sim.boucwen import bouc_wen_operator
from streamid.sim.mrdamper import MRDamperParams, _substeps, damper_force, rk4_segment, velocity_spectrum
from streamid.sim.piezo import PiezoParams, _mode_filter, piezo_excitation

__all__ = [
    "CHANGE_RANGE",
    "DRIFTS",
    "DriftSpec",
    "drift_start_ns",
    "mr_damper_drift",
    "output_change",
    "piezo_drift",
    "simulate_drift",
]

#: Accepted relative change: the scaled parameters stay positive and within a factor 10.
CHANGE_RANGE = (-0.9, 9.0)


def _check_change(change: object) -> float:
    try:
        c = float(change)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        c = math.nan
    lo, hi = CHANGE_RANGE
    if isinstance(change, bool) or not (math.isfinite(c) and lo <= c <= hi):
        raise ConfigError(
            f"the drift change must be a finite number in [{lo:g}, {hi:g}] (a relative change: 0.2 = +20 %); "
            f"got {change!r}"
        )
    return c


# ---------------------------------------------------------------------------
# MR damper
# ---------------------------------------------------------------------------
def _mr_scaled(p: MRDamperParams, factor: float) -> MRDamperParams:
    return dataclasses.replace(
        p, alpha_a=p.alpha_a * factor, alpha_b=p.alpha_b * factor, c0a=p.c0a * factor, c0b=p.c0b * factor
    )


def _integrated(p: MRDamperParams, xl: list[float], vl: list[float], sub: int, n_samples: int, yv: float,
                z: float) -> tuple[list[float], list[float], float, float]:
    ys, zs, yv, z = rk4_segment(p, xl, vl, sub, n_samples, yv, z)
    if not (math.isfinite(yv) and math.isfinite(z)):
        raise ConfigError(
            f"the MR damper integration diverged with {sub} substeps per sample; accepted: a smaller change"
        )
    return ys, zs, yv, z


def mr_damper_drift(
    n_samples: int,
    rng: np.random.Generator | int,
    *,
    drift_at_sample: int,
    change: float = 0.2,
    params: MRDamperParams = MRDamperParams(),
    settle_s: float = 30.0,
) -> Trace:
    """:func:`streamid.sim.simulate_mr_damper` with ``alpha`` and ``c0`` times ``1 + change`` from sample ``k`` on.

    Parameters
    ----------
    n_samples : int
        Samples returned.
    rng : numpy.random.Generator or int
        Draws the excitation, then the force noise (as the undrifted simulator).
    drift_at_sample : int
        ``k``: the force at ``t_k`` and after is the changed damper's (0 <= k <= n_samples;
        ``n_samples`` means no change in the record).
    change : float
        Relative change of ``alpha_a, alpha_b, c0a, c0b`` (0.2 = +20 %), in :data:`CHANGE_RANGE`.
    params : MRDamperParams
        The device before the change.
    settle_s : float
        Lead-in of the undrifted device, simulated and discarded, s.

    Returns
    -------
    Trace
        ``(t_ns, u = velocity [cm/s], y = force [N])``; ``u`` is the undrifted simulation's.
    """
    n = check_positive_int("n_samples", n_samples)
    k_drift = check_nonneg_int("drift_at_sample", drift_at_sample)
    if k_drift > n:
        raise ConfigError(f"drift_at_sample must be in [0, n_samples = {n}]; got {drift_at_sample!r}")
    factor = 1.0 + _check_change(change)
    gen = as_generator(rng)
    v_spec, x_spec = velocity_spectrum(n, params, gen)
    settle = int(round(max(settle_s, 0.0) / params.period_s))
    velocity = np.fft.irfft(v_spec, n)
    x_s = np.fft.irfft(x_spec, n)
    v_max = float(np.max(np.abs(velocity)))
    after = _mr_scaled(params, factor)
    sub0 = _substeps(params, v_max)
    sub1 = max(sub0, _substeps(after, v_max))
    split = settle + k_drift  # first sample (counted from the lead-in's start) of the changed device

    def fine(sub: int, k0: int, k1: int) -> tuple[list[float], list[float]]:
        m = 2 * sub
        xf = np.fft.irfft(x_spec, n * m) * m
        vf = np.fft.irfft(v_spec, n * m) * m
        idx = (np.arange(k0 * m, k1 * m + 1) - settle * m) % (n * m)
        return xf[idx].tolist(), vf[idx].tolist()

    xl, vl = fine(sub0, 0, split)
    ys, zs, yv, z = _integrated(params, xl, vl, sub0, split, xl[0], 0.0)
    force = damper_force(params, ys[settle:], zs[settle:], velocity[:k_drift], x_s[:k_drift])
    if k_drift < n:
        xl, vl = fine(sub1, split, settle + n)
        ys2, zs2, _, _ = _integrated(after, xl, vl, sub1, n - k_drift, yv, z)
        force = np.concatenate([force, damper_force(after, ys2, zs2, velocity[k_drift:], x_s[k_drift:])])
    if params.noise_n > 0:
        force = force + gen.normal(0.0, params.noise_n, size=n)
    return Trace(sample_times_ns(n, params.period_ns), velocity, force)


# ---------------------------------------------------------------------------
# piezo
# ---------------------------------------------------------------------------
def piezo_drift(
    n_samples: int,
    rng: np.random.Generator | int,
    *,
    drift_at_sample: int,
    change: float = 0.2,
    params: PiezoParams = PiezoParams(),
    amplitude_v: float = 100.0,
    settle_s: float = 0.2,
) -> Trace:
    """:func:`streamid.sim.simulate_piezo` with ``d_p`` times ``1 + change`` from sample ``k`` on.

    The hysteresis state ``h`` is carried across the change (the operator
    continues from it with the new ``A d_p``), the bending mode and the sensor
    filter run once over the whole record. ``y[k]`` still equals the undrifted
    output (the mode sees ``u[k]`` one sample later); ``y[k + 1]`` on differ.
    Parameters as :func:`mr_damper_drift` (``amplitude_v``, ``settle_s`` as the
    undrifted simulator's).
    """
    from scipy.signal import butter, lfilter

    n = check_positive_int("n_samples", n_samples)
    k_drift = check_nonneg_int("drift_at_sample", drift_at_sample)
    if k_drift > n:
        raise ConfigError(f"drift_at_sample must be in [0, n_samples = {n}]; got {drift_at_sample!r}")
    factor = 1.0 + _check_change(change)
    p = params
    n_settle = check_nonneg_int("settle samples", int(round(max(settle_s, 0.0) / p.period_s)))
    gen = as_generator(rng)
    total = n + n_settle
    u = piezo_excitation(total, gen, amplitude_v=amplitude_v, period_ns=p.period_ns)
    if n_settle:
        u[:n_settle] *= 0.5 - 0.5 * np.cos(np.pi * np.arange(n_settle) / n_settle)
    # as streamid.sim.piezo._piezo_clean, with the operator split at u[j] (u_ext index j + 1)
    j = n_settle + k_drift
    u_ext = np.concatenate([[0.0], u])
    d_after = p.d_p * factor
    h_ext = bouc_wen_operator(u_ext[: j + 1], alpha=p.hyst_a * p.d_p, beta=1.0, gamma=p.hyst_b,
                              delta=p.hyst_g, nu=1.0)
    if j < total:
        rest = bouc_wen_operator(u_ext[j:], alpha=p.hyst_a * d_after, beta=1.0, gamma=p.hyst_b,
                                 delta=p.hyst_g, nu=1.0, z0=float(h_ext[-1]))
        h_ext = np.concatenate([h_ext, rest[1:]])
    h = h_ext[1:]
    w = np.concatenate([p.d_p * u[:j] - h[:j], d_after * u[j:] - h[j:]])
    b, a = _mode_filter(p)
    y = lfilter(b, a, w)
    if p.sensor_bandwidth_hz is not None:
        sb, sa = butter(2, p.sensor_bandwidth_hz, fs=1.0 / p.period_s)
        y = lfilter(sb, sa, y)
    if p.noise_um > 0:
        y = y + gen.normal(0.0, p.noise_um, size=total)
    return Trace(sample_times_ns(n, p.period_ns), u[n_settle:].copy(), np.asarray(y[n_settle:], np.float64).copy())


# ---------------------------------------------------------------------------
# registry
# ---------------------------------------------------------------------------
DriftSimulator = Callable[..., Trace]


@dataclass(frozen=True)
class DriftSpec:
    """How one device drifts.

    Attributes
    ----------
    device : str
        Registry name (:data:`streamid.sim.DEVICES`).
    simulate : callable
        ``simulate(n_samples, rng, *, drift_at_sample, change) -> Trace``.
    period_ns : int
        The device's sample period.
    parameters : tuple of str
        Names of the scaled parameters (fields of the device's params dataclass).
    lag_samples : int
        Samples between the change and the first output sample that can differ.
    """

    device: str
    simulate: DriftSimulator
    period_ns: int
    parameters: tuple[str, ...]
    lag_samples: int


_DRIFTS = {
    "mr_damper": DriftSpec("mr_damper", mr_damper_drift, MRDamperParams().period_ns,
                           ("alpha_a", "alpha_b", "c0a", "c0b"), 0),
    "piezo": DriftSpec("piezo", piezo_drift, PiezoParams().period_ns, ("d_p",), 1),
}

#: Devices that can drift, by name (read-only).
DRIFTS: Mapping[str, DriftSpec] = MappingProxyType(_DRIFTS)


def _spec(device: str) -> DriftSpec:
    spec = DRIFTS.get(device) if isinstance(device, str) else None
    if spec is None:
        raise ConfigError(f"a drifting device must be one of {', '.join(DRIFTS)}; got {device!r}")
    return spec


def _drift_sample(spec: DriftSpec, drift_at_s: object) -> int:
    try:
        s = float(drift_at_s)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        s = math.nan
    if isinstance(drift_at_s, bool) or not (math.isfinite(s) and s >= 0):
        raise ConfigError(f"drift_at_s must be a finite time >= 0 s from the record's start; got {drift_at_s!r}")
    return -(-int(round(s * 1e9)) // spec.period_ns)  # ceil: the first sample at or after the change


def drift_start_ns(device: str, drift_at_s: float) -> int:
    """Time of the first sample of the changed device: ``ceil(drift_at_ns / period_ns) * period_ns``."""
    spec = _spec(device)
    return _drift_sample(spec, drift_at_s) * spec.period_ns


def simulate_drift(
    device: str,
    seconds: float,
    drift_at_s: float,
    change: float = 0.2,
    rng: np.random.Generator | int = 0,
) -> Trace:
    """Simulate ``seconds`` of ``device`` whose output-level parameters change by ``change`` at ``drift_at_s``.

    Parameters
    ----------
    device : str
        ``"mr_damper"`` or ``"piezo"`` (:data:`DRIFTS`).
    seconds : float
        Record length (at least the device's ``min_seconds``).
    drift_at_s : float
        Time of the change from the record's start, s; must be inside the record.
    change : float
        Relative change (0.2 = +20 %), in :data:`CHANGE_RANGE`.
    rng : numpy.random.Generator or int
        Same seed, same record; the record before the change equals
        ``get_device(device).simulate_seconds(seconds, rng)``'s exactly.

    Raises
    ------
    ConfigError
        Unknown device, change out of range, or ``drift_at_s`` outside ``[0, seconds)``.
    """
    from streamid.sim.registry import ALIASES, get_device

    name = ALIASES.get(device, device) if isinstance(device, str) else device
    spec = _spec(name)
    n = get_device(name).n_samples(seconds)
    k = _drift_sample(spec, drift_at_s)
    if k >= n:
        raise ConfigError(
            f"drift_at_s must fall inside the {n * spec.period_ns / 1e9:g} s record, i.e. in [0, "
            f"{(n - 1) * spec.period_ns / 1e9:g}] s; got {drift_at_s!r}"
        )
    return spec.simulate(n, as_generator(rng), drift_at_sample=k, change=_check_change(change))


def output_change(
    device: str, seconds: float, drift_at_s: float, change: float, seed: int, *, noise: bool = False,
    block_s: float = 0.5, within_s: float = 3.0,
) -> dict[str, float]:
    """How much the change moves the output after ``drift_at_s`` (noise-free by default).

    Returns ``rms_ratio`` (RMS of the drifted output about its mean over RMS of the
    undrifted one, after the change), ``rms_diff_rel`` (RMS of the difference over
    the undrifted output's RMS about its mean), ``max_abs_diff_before`` (0.0 when
    the record before the change is identical), and ``block_level_min`` /
    ``block_level_max``: the smallest and largest ``log`` of that RMS ratio over the
    whole blocks of ``block_s`` that start at the change and end within ``within_s``
    of it (the drift monitor's level, :mod:`streamid.online.drift`, measured on the
    device itself: how much of the change the excitation shows, block by block).
    """
    spec = _spec(device)
    n = _drift_sample(spec, drift_at_s)
    kw: dict[str, object] = {}
    if not noise:
        kw["params"] = (dataclasses.replace(MRDamperParams(), noise_n=0.0) if device == "mr_damper"
                        else dataclasses.replace(PiezoParams(), noise_um=0.0))
    from streamid.sim.registry import get_device

    total = get_device(device).n_samples(seconds)
    base = spec.simulate(total, seed, drift_at_sample=total, change=0.0, **kw).y
    drifted = spec.simulate(total, seed, drift_at_sample=n, change=change, **kw).y
    b, d = base[n:], drifted[n:]
    sd_b = float(np.sqrt(np.mean((b - b.mean()) ** 2)))
    per_s = total / seconds
    block = max(2, round(block_s * per_s))
    blocks = min(b.size, round(within_s * per_s)) // block
    if blocks < 1:
        raise ConfigError(f"within_s must hold at least one block of block_s = {block_s!r} s after the change "
                          f"(and the record must reach that far); got within_s = {within_s!r}")
    sb = (b[: blocks * block].reshape(blocks, block), d[: blocks * block].reshape(blocks, block))
    rb, rd = (np.sqrt(np.mean((x - x.mean(axis=1, keepdims=True)) ** 2, axis=1)) for x in sb)
    levels = np.log(rd / rb)
    return {
        "rms_ratio": float(np.sqrt(np.mean((d - d.mean()) ** 2))) / sd_b,
        "rms_diff_rel": float(np.sqrt(np.mean((d - b) ** 2))) / sd_b,
        "max_abs_diff_before": float(np.max(np.abs(drifted[:n] - base[:n]))) if n else 0.0,
        "block_level_min": float(levels.min()),
        "block_level_max": float(levels.max()),
    }


def _main(argv: list[str]) -> int:
    """``python -m streamid.sim.drift [CHANGE ...]``: print :func:`output_change` for both devices."""
    changes = [float(a) for a in argv] or [0.2, -0.2]
    for device, seconds, at, block_s in (("mr_damper", 60.0, 30.0, 0.5), ("piezo", 2.0, 1.0, 0.05)):
        for change in changes:
            for seed in range(3):
                r = output_change(device, seconds, at, change, seed, block_s=block_s, within_s=min(3.0, seconds - at))
                print(f"{device:<10} change {change:+.2f} seed {seed}: rms_ratio {r['rms_ratio']:.4f} "
                      f"rms_diff_rel {r['rms_diff_rel']:.4f} before {r['max_abs_diff_before']:g} "
                      f"level per {block_s:g} s block {r['block_level_min']:+.3f}..{r['block_level_max']:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
