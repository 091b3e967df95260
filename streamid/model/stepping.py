"""A model run as a simulator, sample by sample: the free run behind :meth:`Predictor.step
<streamid.model.predictor.Predictor.step>`.

:class:`FreeRun` starts from measured samples (the newest ``max_lag`` a predictor holds) and then feeds only its
own predictions back, one instant per :meth:`~FreeRun.advance`, as an FMU's ``doStep`` or the generated C code's
``<name>_step`` does. Each instant gives a :class:`Step`: the output, the band of the model's interval and whether
the instant is inside the estimation domain, computed as :meth:`Model.simulate(u, y_init, interval=level)
<streamid.model.narx.Model.simulate>` computes them over a whole record (tested to 1e-9 relative):

* every network of an ensemble runs on its own past outputs from its own ``max_lag`` on (a member with a shorter
  memory than the ensemble's free-runs over the last measured samples too, as in :meth:`EnsembleModel.member_paths
  <streamid.model.ensemble.EnsembleModel.member_paths>`); the output is their mean or median, never fed back;
* the band is ``y -+ q_level (scale + std of the members' outputs + beyond * far)``
  (:mod:`~streamid.model.uncertainty`), ``far`` the farthest regressor's distance beyond its estimation range
  times the output's half-range (:func:`~streamid.model.domain.far_from_domain`);
* ``in_domain`` is False when a regressor of the instant (an input, or the run's own past output) lies outside
  its estimation range (:func:`~streamid.model.domain.outside`, the FMU's ``<output>_in_domain``).

The state is a few fixed-size rings (``2 (max_lag + 1)`` rows each: every sample is written twice, at its slot and
``max_lag + 1`` rows later, so the newest ``max_lag`` samples before an instant are always contiguous, as the
compiled one-row kernel reads them): an instant costs the members' one-row evaluations and a few small array
operations, the same at the millionth instant as at the first.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Real
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.model.domain import signal_excess, signal_outside
from streamid.model.ensemble import EnsembleModel, members_of
from streamid.model.narx import Model

__all__ = ["FreeRun", "Step", "band_quantile"]


@dataclass(frozen=True, slots=True)
class Step:
    """One instant of a free run (output units).

    ``y`` the model's output; ``lower`` and ``upper`` its band at the level asked (None when the model carries no
    interval or none was asked); ``in_domain`` whether every regressor of the instant lies inside the model's
    estimation domain (False: the model extrapolates; trust ``y`` less, the band has grown by how far).
    """

    y: float
    lower: float | None
    upper: float | None
    in_domain: bool


class OneRow(Protocol):
    """One network prepared for one row at a time (the predictor's ``_Network``)."""

    def yn(self, un: NDArray[np.float64], yn: NDArray[np.float64], n: int) -> float: ...


def band_quantile(model: Model, level: object) -> float | None:
    """The quantile of ``model``'s interval at ``level`` (None: no level asked, or the model carries no interval).

    Raises
    ------
    DataError
        If ``level`` is not one of the levels the model was calibrated at.
    """
    if level is None or model.interval is None:
        return None
    if isinstance(level, bool) or not isinstance(level, Real):
        raise DataError(f"interval must be a number, one of {', '.join(f'{v:g}' for v in model.interval.levels)} "
                        f"(the levels this model was calibrated at), or None; got {level!r}")
    return model.interval.quantile(float(level))


class FreeRun:
    """The free run of ``model`` from measured samples (see the module docstring).

    Parameters
    ----------
    model
        The model (its interval and domain are read here).
    nets
        Its networks prepared for one row each (in :func:`~streamid.model.ensemble.members_of`'s order).
    u, y
        The newest ``max_lag`` measured samples, raw: ``u`` (max_lag, n_inputs), ``y`` (max_lag,).
    un, yn
        The same in the model's normalised units.
    """

    def __init__(self, model: Model, nets: Sequence[OneRow], u: NDArray[np.float64], y: NDArray[np.float64],
                 un: NDArray[np.float64], yn: NDArray[np.float64]) -> None:
        members = members_of(model)
        L = model.max_lag
        self._cap = cap = L + 1
        self._nets = list(nets)
        self._lags = [m.max_lag for m in members]
        self._median = isinstance(model, EnsembleModel) and model.combine == "median"
        norm = model.normalisation
        self._y_low, self._y_half = norm.y_low, norm.y_half_range
        self._u_low, self._u_high = np.asarray(norm.u_low, dtype=np.float64), np.asarray(norm.u_high, dtype=np.float64)
        self._yb = (np.float64(norm.y_low), np.float64(norm.y_high))
        interval = model.interval
        self._scale = 0.0 if interval is None else interval.scale
        self._beyond = 0.0 if interval is None else interval.beyond
        regs = {r for m in members for r in (*m.regressors, *(m.linear_regressors or ()))}
        self._ru = np.array([r.lag for r in regs if r.signal == "u"], dtype=np.int64)
        self._ri = np.array([r.index for r in regs if r.signal == "u"], dtype=np.int64)
        self._ry = np.array([r.lag for r in regs if r.signal == "y"], dtype=np.int64)
        rows, n_in = 2 * cap, u.shape[1]
        self._un = np.zeros((rows, n_in))
        self._ynk = np.zeros((len(self._nets), rows))  # each network's own normalised outputs
        self._ex_u, self._out_u = np.zeros((rows, n_in)), np.zeros((rows, n_in), dtype=bool)
        self._ex_y, self._out_y = np.zeros(rows), np.zeros(rows, dtype=bool)
        self._j = 0  # instants written (the measured ones first)
        self.steps = 0  #: instants simulated since the start
        for k in range(L):  # the measured samples; a member with a shorter memory runs on from its own max_lag
            self._write_u(u[k], un[k])
            n = self._j % cap + cap
            for c, net in enumerate(self._nets):
                v = yn[k] if k < self._lags[c] else net.yn(self._un, self._ynk[c], n)
                self._ynk[c, n] = self._ynk[c, n - cap] = v
            self._write_y(y[k])
            self._j += 1

    def _write_u(self, u: NDArray[np.float64], un: NDArray[np.float64]) -> None:
        p = self._j % self._cap
        for a, v in ((self._un, un), (self._ex_u, signal_excess(u, self._u_low, self._u_high)),
                     (self._out_u, signal_outside(u, self._u_low, self._u_high))):
            a[p] = a[p + self._cap] = v

    def _write_y(self, y: float) -> None:
        p = self._j % self._cap
        ya = np.asarray(y, dtype=np.float64)  # 0-d: the same operations as a record's
        self._ex_y[p] = self._ex_y[p + self._cap] = signal_excess(ya, *self._yb)
        self._out_y[p] = self._out_y[p + self._cap] = signal_outside(ya, *self._yb)

    def advance(self, u: NDArray[np.float64], un: NDArray[np.float64], q: float | None) -> Step:
        """The next instant from its input ``u`` (n_inputs,) (``un``: normalised), its band's quantile ``q``."""
        cap = self._cap
        self._write_u(u, un)
        n = self._j % cap + cap
        outs = []
        for c, net in enumerate(self._nets):
            v = net.yn(self._un, self._ynk[c], n)
            self._ynk[c, n] = self._ynk[c, n - cap] = v
            outs.append((v + 1.0) * self._y_half + self._y_low)  # Normalisation.y_inverse, a member's output
        K = len(outs)
        if K == 1:
            y = outs[0]
        elif self._median:  # numpy's median: the middle value, or the mean of the middle two
            s = sorted(outs)
            y = math.nan if any(math.isnan(v) for v in outs) else (s[K // 2] if K % 2 else (s[K // 2 - 1] + s[K // 2]) / 2.0)
        else:
            y = sum(outs) / K
        rows_u, rows_y = n - self._ru, n - self._ry  # the regressors' samples (the y's: the run's own outputs)
        inside = not (bool(self._out_u[rows_u, self._ri].any()) or bool(self._out_y[rows_y].any()))
        lower = upper = None
        if q is not None:
            width = self._scale
            if K > 1:  # the members' standard deviation (population, as numpy's std)
                mean = sum(outs) / K
                width += math.sqrt(sum((v - mean) ** 2 for v in outs) / K)
            if self._beyond > 0.0:
                ex = max(float(self._ex_u[rows_u, self._ri].max(initial=0.0)), float(self._ex_y[rows_y].max(initial=0.0)))
                width += self._beyond * (ex * self._y_half)
            half = q * width
            lower, upper = y - half, y + half
        self._write_y(y)
        self._j += 1
        self.steps += 1
        return Step(y, lower, upper, inside)
