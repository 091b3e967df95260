"""Recalibration of a drifted champion: the same network in a new output scale (gain and offset).

A NARX model works in normalised units, ``y_n = 2 (y - low) / (high - low) - 1``
(:class:`~streamid.model.regressors.Normalisation`).  If the device's output
becomes ``a y + b`` for the same input (a change of gain and offset: the
common drift of a physical device, see :mod:`streamid.online.drift`), the
model with ``low' = a low + b`` and ``high' = a high + b`` sees exactly the
normalised signals it was trained on and predicts ``a yhat + b``: its one-step
and free-run behaviour carry over, in the new scale, with no retraining.

:func:`recalibrate` fits ``a`` and ``b`` by least squares of the measured output
on the model's free run over the given data (the free run started from the
measured outputs in the current scale, so the fit is repeated on the rescaled
model until it settles: a few rounds).  After a drift, the online update offers
the recalibrated champion next to the identified challenger, and the better of
the two on the held-out data goes to the champion/challenger rule
(:mod:`streamid.online.acceptance`): it is served only if it beats the drifted
champion there by the margin, like any challenger.

An ensemble (``streamid.model/3``, :mod:`streamid.model.ensemble`) has one normalisation shared by its
members: replacing it rescales every member, so the gain and offset fitted on the mean's free run apply to
the mean (tests/test_engine_ensemble.py). The online updates themselves never make an ensemble (one run each).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.model import Model

__all__ = ["recalibrate", "MAX_GAIN_CHANGE"]

#: Largest gain change a recalibration makes (factor either way); beyond it the device changed too much
#: for the same network to hold, and only a new identification can serve.
MAX_GAIN_CHANGE = 2.0

_ROUNDS = 4


def recalibrate(model: Model, u: NDArray[np.float64], y: NDArray[np.float64]) -> Model | None:
    """``model`` rescaled to the output level of ``u``/``y`` (see the module docstring); None if it cannot be.

    None when the free run is not finite, the output or the run is constant, or the fitted gain is outside
    ``[1 / MAX_GAIN_CHANGE, MAX_GAIN_CHANGE]`` (a negative gain included).
    """
    L = model.max_lag
    if y.shape[0] <= L + 2:
        return None
    current, a_total = model, 1.0
    for _ in range(_ROUNDS):
        with np.errstate(over="ignore", invalid="ignore"):
            sim = current.simulate(u, y[:L])[L:]
        yy = y[L:]
        if not np.all(np.isfinite(sim)):
            return None
        sc, yc = sim - sim.mean(), yy - yy.mean()
        ss = float(sc @ sc)
        if not ss > 0 or not float(yc @ yc) > 0:
            return None
        a = float(sc @ yc) / ss
        b = float(yy.mean() - a * sim.mean())
        a_total *= a
        if not 1.0 / MAX_GAIN_CHANGE <= a_total <= MAX_GAIN_CHANGE:
            return None
        n = current.normalisation
        current = dataclasses.replace(
            current, normalisation=dataclasses.replace(n, y_low=a * n.y_low + b, y_high=a * n.y_high + b))
        if abs(a - 1.0) < 1e-4 and abs(b) < 1e-6 * abs(n.y_high - n.y_low):
            break
    n0, n1 = model.normalisation, current.normalisation
    gain = (n1.y_high - n1.y_low) / (n0.y_high - n0.y_low)
    offset = n1.y_low - gain * n0.y_low
    if current.interval is not None:  # its errors are in the new scale too: the band's scale (output units) follows
        current = dataclasses.replace(current, interval=dataclasses.replace(current.interval,
                                                                            scale=current.interval.scale * abs(gain)))
    return current.with_metrics(recalibrated_gain=float(gain), recalibrated_offset=float(offset))


def describe(model: Any) -> str:
    """``" (champion recalibrated: gain 1.17, offset -3.2)"`` for a recalibrated model, else ``""``."""
    m = getattr(model, "metrics", {}) or {}
    if "recalibrated_gain" not in m:
        return ""
    return f" (champion recalibrated: gain {m['recalibrated_gain']:.3g}, offset {m['recalibrated_offset']:.3g})"
