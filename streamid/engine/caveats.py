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
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.longlinear import dense_regressors
from streamid.engine.regressors import regressor_columns

__all__ = ["BEYOND_RANGE", "MARGINAL_RADIUS", "OSA_GOOD", "arx_pole_radius", "model_caveats"]

#: A validation signal counts as beyond the estimation range when it leaves it by more than this fraction of the
#: estimation span (the free-run range guard of the final choice allows 0.25 of it; docs/method.md).
BEYOND_RANGE = 0.25
#: One-step-ahead validation R^2 from which a model is called a good one-step predictor.
OSA_GOOD = 0.9
#: Pole radius of the second-order ARX fit from which the plant is called integrating or unstable.
MARGINAL_RADIUS = 0.99


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


def _beyond(name: str, est: NDArray[np.float64], val: NDArray[np.float64]) -> str | None:
    lo, hi = float(np.min(est)), float(np.max(est))
    span = hi - lo
    vlo, vhi = float(np.min(val)), float(np.max(val))
    if not span > 0 or max(vhi - hi, lo - vlo) <= BEYOND_RANGE * span:
        return None
    share = float(np.mean((val < lo) | (val > hi)))
    return (f"the validation {name} spans [{vlo:.4g}, {vhi:.4g}], beyond the estimation range [{lo:.4g}, {hi:.4g}] "
            f"({share:.0%} of its samples outside): a Gaussian RBF network does not extrapolate, so the validation "
            f"figures there judge data the model never saw the like of; estimate on data that span the range of use")


def model_caveats(r2: dict[str, float], u_est: NDArray[np.float64], y_est: NDArray[np.float64],
                  u_val: NDArray[np.float64] | None, y_val: NDArray[np.float64] | None,
                  input_names: tuple[str, ...] = (), output_name: str = "y") -> list[str]:
    """Caveats on a kept model from its R^2 (``osa_est``, ``fr_est``, ``osa_val``, ``fr_val``: nan when absent) and
    the data (see the module docstring); an empty list when there is nothing to say."""
    out: list[str] = []
    ue = np.asarray(u_est, dtype=np.float64).reshape(len(y_est), -1)
    if y_val is not None and u_val is not None and len(y_val):
        uv = np.asarray(u_val, dtype=np.float64).reshape(len(y_val), -1)
        names = input_names or tuple(f"u{j}" for j in range(ue.shape[1]))
        for j in range(ue.shape[1]):
            note = _beyond(f"input {names[j]}", ue[:, j], uv[:, j])
            if note:
                out.append(note)
        note = _beyond(f"output {output_name}", np.asarray(y_est, dtype=np.float64), np.asarray(y_val, dtype=np.float64))
        if note:
            out.append(note)
    osa, fr = r2.get("osa_val", float("nan")), r2.get("fr_val", float("nan"))
    if osa >= OSA_GOOD and fr < 0.0:
        why = ""
        radius = arx_pole_radius(ue, np.asarray(y_est, dtype=np.float64))
        if radius >= MARGINAL_RADIUS:
            why = (f"; a second-order linear ARX fit of the estimation data has a pole at |z| = {radius:.3f}: the plant "
                   f"integrates or is unstable in open loop, and every open-loop simulation of it drifts (judge such a "
                   f"model one step ahead, or identify the closed loop)")
        out.append(f"a one-step predictor, not a simulator: one-step-ahead R2 on the validation data {osa:.4f}, "
                   f"free run {_fmt(fr)} (worse than the data's mean){why}")
    fr_est = r2.get("fr_est", float("nan"))
    if fr_est < 0.0:
        out.append(f"its free run does not explain even its estimation record (free-run R2 {_fmt(fr_est)}): do not "
                   f"use it to simulate this device")
    return out


def _fmt(v: Any) -> str:
    return f"{v:.4f}" if np.isfinite(v) else str(v)
