"""What a user should know before trusting a kept model: plain-language caveats from its figures and the data.

:func:`model_caveats` is pure (numbers in, sentences out) and is what ``streamid identify`` prints under the kept
model and writes to its report (``caveats``).  Each caveat names the figure that raised it and what to do:

* **validation beyond the estimation range** -- a Gaussian RBF network does not extrapolate: where the validation
  output (or an input) leaves the range the estimation data spanned, its predictions there are unsupported.  The
  ball and beam of the tuning suite: validation output up to 0.177 against an estimation maximum of 0.087.
* **a one-step predictor, not a simulator** -- one-step-ahead R^2 on the validation data of at least
  :data:`OSA_GOOD` while the free run there is worse than the data's mean (R^2 below 0).  With it, when a
  second-order linear ARX fit of the estimation data has a pole at or beyond :data:`MARGINAL_RADIUS`, the
  likely reason: the plant integrates or is unstable in open loop, and every open-loop simulation of it drifts
  (the ball and beam: poles at 0.998; docs/engine-results.md, round 3).
* **no free run of its own record** -- the estimation free-run R^2 is below 0: the model does not simulate even
  the data it was fitted to.
* **a free run that diverged** -- the simulation left the numbers (inf or NaN) at a named sample: it has no
  free-run R^2 there (null in the reports, never an error that takes the report down; issue 37).
* **much larger than a close competitor** -- the kept model fits at least :data:`SIZE_RATIO` times as many weights
  as another run's candidate whose estimation free-run error is at most :data:`ERROR_RATIO` times the kept one's
  (:func:`size_caveat`): the choice by the estimation record's criterion took a small gain there, which a second
  experiment often does not confirm (issue 37: a real piezo's 30-neuron, 30-lag model kept for 0.99992 against
  0.99988, then -3.96 on the next record).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.choice.longlinear import dense_regressors
from streamid.model.regressors import regressor_columns
from streamid.model.domain import BEYOND_RANGE, beyond_bounds, beyond_range

__all__ = ["BEYOND_RANGE", "ERROR_RATIO", "MARGINAL_RADIUS", "OSA_GOOD", "SIZE_RATIO", "arx_pole_radius",
           "beyond_range", "divergence_caveat", "model_caveats", "range_caveats", "record_caveats", "size_caveat",
           "summed_record_caveats"]

#: One-step-ahead validation R^2 from which a model is called a good one-step predictor.
OSA_GOOD = 0.9
#: Pole radius of the second-order ARX fit from which the plant is called integrating or unstable.
MARGINAL_RADIUS = 0.99
#: A kept model this many times the weights of a close competitor is called much larger (:func:`size_caveat`).
SIZE_RATIO = 2.0
#: A competitor is close when its estimation free-run error ``1 - R^2`` is at most this many times the kept one's.
ERROR_RATIO = 2.0


def arx_pole_radius(u: NDArray[np.float64], y: NDArray[np.float64], order: int = 2) -> float:
    """The largest pole modulus of a least-squares linear ARX fit of ``order`` (``y(t-1..t-n)``, every input's
    ``u(t-1..t-n)`` and a constant) of ``u`` (N, n_inputs) and ``y`` (N,); nan when the record is too short."""
    u2 = np.asarray(u, dtype=np.float64).reshape(len(y), -1)
    y1 = np.asarray(y, dtype=np.float64)
    n = order
    rows = y1.shape[0] - n
    if rows < 4 * (n * (1 + u2.shape[1]) + 1):
        return float("nan")
    regs = dense_regressors(n, u2.shape[1], direct=False)  # y(t-k) and every input's u(t-k), k = 1..n
    X = np.column_stack([regressor_columns(regs, u2, y1, n), np.ones(rows)])
    coef = np.linalg.lstsq(X, y1[n:], rcond=None)[0]
    a = [c for c, r in zip(coef, regs) if r.signal == "y"]
    return float(np.max(np.abs(np.roots(np.concatenate([[1.0], -np.asarray(a)])))))


def _beyond(name: str, lo: float, hi: float, val: NDArray[np.float64]) -> str | None:
    if not beyond_range(lo, hi, val):
        return None
    return _beyond_text(name, lo, hi, float(np.min(val)), float(np.max(val)), float(np.mean((val < lo) | (val > hi))))


def _beyond_text(name: str, lo: float, hi: float, vlo: float, vhi: float, share: float) -> str:
    return (f"the validation {name} spans [{vlo:.4g}, {vhi:.4g}], beyond the estimation range [{lo:.4g}, {hi:.4g}] "
            f"({share:.0%} of its samples outside): a Gaussian RBF network does not extrapolate, so the validation "
            f"figures there judge data the model never saw the like of; estimate on data that span the range of use")


def range_caveats(u_range: tuple[tuple[float, ...], tuple[float, ...]], y_range: tuple[float, float],
                  u_val: NDArray[np.float64], y_val: NDArray[np.float64], input_names: tuple[str, ...] = (),
                  output_name: str = "y") -> list[str]:
    """A caveat per validation signal that leaves its estimation range (``(lows, highs)`` of the inputs, ``(low,
    high)`` of the output) by more than :data:`BEYOND_RANGE` of its span."""
    if not len(y_val):
        return []
    uv = np.asarray(u_val, dtype=np.float64).reshape(len(y_val), -1)
    names = input_names or tuple(f"u{j}" for j in range(uv.shape[1]))
    notes = [_beyond(f"input {names[j]}", float(u_range[0][j]), float(u_range[1][j]), uv[:, j])
             for j in range(uv.shape[1])]
    notes.append(_beyond(f"output {output_name}", float(y_range[0]), float(y_range[1]),
                         np.asarray(y_val, dtype=np.float64)))
    return [n for n in notes if n]


def divergence_caveat(data: str, at: int | None) -> list[str]:
    """'Its free run diverged' on ``data`` (e.g. "validation data") from sample ``at`` (None: it did not)."""
    if at is None:
        return []
    return [f"its free run on the {data} diverged (no longer a finite number from sample {at}): it has no free-run "
            f"R2 there (null in the report); the model is unstable under this excitation: do not use it to simulate "
            f"it, and estimate on data that span it"]


def _simulator_caveat(osa: float, fr: float | None, u: NDArray[np.float64] | None, y: NDArray[np.float64] | None,
                      data: str, radius: float | None = None) -> list[str]:
    """'A one-step predictor, not a simulator', with the likely reason read from ``u``/``y`` (``data`` names them;
    or their ARX pole ``radius`` given, then ``u``/``y`` None); nothing for a diverged free run (``fr`` None:
    :func:`divergence_caveat` says it)."""
    if fr is None or not (osa >= OSA_GOOD and fr < 0.0):
        return []
    why = ""
    if radius is None:
        assert u is not None and y is not None
        radius = arx_pole_radius(u, y)
    if radius >= MARGINAL_RADIUS:
        why = (f"; a second-order linear ARX fit of the {data} has a pole at |z| = {radius:.3f}: the plant "
               f"integrates or is unstable in open loop, and every open-loop simulation of it drifts (judge such a "
               f"model one step ahead, or identify the closed loop)")
    return [f"a one-step predictor, not a simulator: one-step-ahead R2 on the validation data {osa:.4f}, "
            f"free run {_fmt(fr)} (worse than the data's mean){why}"]


def model_caveats(r2: dict[str, float | None], u_est: NDArray[np.float64], y_est: NDArray[np.float64],
                  u_val: NDArray[np.float64] | None, y_val: NDArray[np.float64] | None,
                  input_names: tuple[str, ...] = (), output_name: str = "y",
                  diverged: dict[str, int] | None = None) -> list[str]:
    """Caveats on a kept model from its R^2 (``osa_est``, ``fr_est``, ``osa_val``, ``fr_val``: nan when absent,
    None for a free run that diverged, ``diverged`` naming its first non-finite sample per part ``"est"``/``"val"``)
    and the data (see the module docstring); an empty list when there is nothing to say."""
    out: list[str] = []
    ue = np.asarray(u_est, dtype=np.float64).reshape(len(y_est), -1)
    ye = np.asarray(y_est, dtype=np.float64)
    if y_val is not None and u_val is not None:
        out += range_caveats((tuple(ue.min(axis=0)), tuple(ue.max(axis=0))), (float(ye.min()), float(ye.max())),
                             u_val, y_val, input_names, output_name)
    osa_val = r2.get("osa_val", float("nan"))
    out += _simulator_caveat(float("nan") if osa_val is None else osa_val, r2.get("fr_val", float("nan")), ue, ye,
                             "estimation data")
    for part, data in (("est", "estimation data"), ("val", "validation data")):
        out += divergence_caveat(data, (diverged or {}).get(part))
    fr_est = r2.get("fr_est", float("nan"))
    if fr_est is not None and fr_est < 0.0:
        out.append(f"its free run does not explain even its estimation record (free-run R2 {_fmt(fr_est)}): do not "
                   f"use it to simulate this device")
    return out


def size_caveat(params: float, r2_fr_est: float | None, complexity: dict[str, Any] | None) -> list[str]:
    """'Much larger than a close competitor' (see the module docstring) for a kept model of ``params`` fitted weights
    and estimation free-run R^2 ``r2_fr_est``, from the final choice's evidence ``complexity`` (``metrics.complexity``:
    every run's candidate with its ``params`` and ``r2_fr_est``); the smallest such competitor is named."""
    if not complexity or r2_fr_est is None or not np.isfinite(r2_fr_est):
        return []
    err = max(1.0 - float(r2_fr_est), 1e-12)
    close = [c for c in complexity.get("candidates", ())
             if c.get("r2_fr_est") is not None and c.get("params") and params >= SIZE_RATIO * float(c["params"])
             and 1.0 - float(c["r2_fr_est"]) <= ERROR_RATIO * err]
    if not close:
        return []
    c = min(close, key=lambda c: (float(c["params"]), -float(c["r2_fr_est"])))
    kind = " with a linear part" if c.get("linear") else ""
    return [f"the kept model fits {params:g} weights, {params / float(c['params']):.1f} times the {float(c['params']):g} of "
            f"restart {c['run']}'s ({c['neurons']} neurons{kind}, lags 1..{c['lag_space']}), whose estimation free-run "
            f"R2 {float(c['r2_fr_est']):.5f} is close to the kept one's {float(r2_fr_est):.5f} (its error at most "
            f"{ERROR_RATIO:g} times as large): the choice by {complexity.get('rule', 'the criterion')} on the "
            f"estimation record took that small gain, which another experiment often does not confirm; judge on a "
            f"second record (streamid identify --validate SECOND_RECORD, or streamid validate MODEL RECORD); "
            f"--neurons {c['neurons']} --max-lag {c['lag_space']} identifies at that size"]


def record_caveats(model: Any, osa: float, fr: float | None, u: NDArray[np.float64], y: NDArray[np.float64],
                   diverged_at: int | None = None) -> list[str]:
    """Caveats on ``model`` judged on a record it never saw (``streamid validate``): the record's signals beyond
    the model's estimation range (its normalisation keeps that range), a one-step predictor that does not
    simulate (the likely reason read from the record itself), and a free run that diverged (``fr`` None, from
    sample ``diverged_at``)."""
    n = model.normalisation
    u2 = np.asarray(u, dtype=np.float64).reshape(len(y), -1)
    y1 = np.asarray(y, dtype=np.float64)
    return (range_caveats((n.u_low, n.u_high), (n.y_low, n.y_high), u2, y1, tuple(model.input_names),
                          model.output_name)
            + _simulator_caveat(osa, fr, u2, y1, "data") + divergence_caveat("record", diverged_at))


def summed_record_caveats(model: Any, osa: float, fr: float | None, ranges: list[tuple[float, float, int]], n: int,
                          radius: float, diverged_at: int | None = None) -> list[str]:
    """:func:`record_caveats` from a record's summable figures (a record read a piece at a time:
    :mod:`streamid.engine.streamed`): ``ranges`` each input's then the output's ``(min, max, samples outside the
    model's range)`` over its ``n`` samples, ``radius`` :func:`arx_pole_radius` of it."""
    nm = model.normalisation
    bounds = [*zip(nm.u_low, nm.u_high), (nm.y_low, nm.y_high)]
    names = [f"input {c}" for c in model.input_names] + [f"output {model.output_name}"]
    out = []
    for name, (lo, hi), (vlo, vhi, k) in zip(names, bounds, ranges):
        lo, hi = float(lo), float(hi)
        if n and beyond_bounds(lo, hi, vlo, vhi):
            out.append(_beyond_text(name, lo, hi, vlo, vhi, k / n))
    return out + _simulator_caveat(osa, fr, None, None, "data", radius) + divergence_caveat("record", diverged_at)


def _fmt(v: Any) -> str:
    return f"{v:.4f}" if np.isfinite(v) else str(v)
