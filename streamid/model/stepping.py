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
from streamid.model.domain import value_excess, value_outside
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
    """The free run of ``model`` from measured samples (see the module docstring): :meth:`seed`, then
    :meth:`advance` an instant at a time (the rings are allocated once, for every seed).

    Parameters
    ----------
    model
        The model (its interval and domain are read here).
    nets
        Its networks prepared for one row each (in :func:`~streamid.model.ensemble.members_of`'s order).
    """

    def __init__(self, model: Model, nets: Sequence[OneRow]) -> None:
        members = members_of(model)
        L = model.max_lag
        self._cap = cap = L + 1
        self._nets = list(nets)
        self._lags = [m.max_lag for m in members]
        self._median = isinstance(model, EnsembleModel) and model.combine == "median"
        norm = model.normalisation
        self._y_low, self._y_half = norm.y_low, norm.y_half_range
        # each signal's estimation range: the inputs', then the output's (the domain rings' columns)
        self._ranges = [(float(a), float(b)) for a, b in zip(norm.u_low, norm.u_high)] + [(norm.y_low, norm.y_high)]
        interval = model.interval
        self._scale = 0.0 if interval is None else interval.scale
        self._beyond = 0.0 if interval is None else interval.beyond
        regs = {r for m in members for r in (*m.regressors, *(m.linear_regressors or ()))}
        rows, n_in = 2 * cap, model.n_inputs
        self._rlags = np.array([r.lag for r in regs], dtype=np.int64)  # every regressor: its lag and its column
        self._rcols = np.array([r.index if r.signal == "u" else n_in for r in regs], dtype=np.int64)
        self._un = np.zeros((rows, n_in))
        self._ynk = np.zeros((len(self._nets), rows))  # each network's own normalised outputs
        # each sample's signals: how far beyond (domain.excess) and whether outside (domain.outside) their ranges
        self._ex, self._out = np.zeros((rows, n_in + 1)), np.zeros((rows, n_in + 1), dtype=bool)
        self._j = 0  # instants written (the measured ones first)
        self.steps = 0  #: instants simulated since the last seed

    def seed(self, u: NDArray[np.float64], y: NDArray[np.float64], un: NDArray[np.float64],
             yn: NDArray[np.float64]) -> None:
        """Start again from the newest ``max_lag`` measured samples: ``u`` (max_lag, n_inputs), ``y`` (max_lag,)
        raw, ``un``, ``yn`` the same normalised (slots 0 .. max_lag - 1 and their mirrors: no wrap yet)."""
        cap, L = self._cap, self._cap - 1
        if L:  # a model of direct terms only (max_lag 0) starts from nothing
            cols = [*zip(*u.tolist()), y.tolist()]  # each signal's samples: the inputs', the output's
            # how far beyond and whether outside each signal's range, as advance judges one sample
            ex = np.array([[value_excess(v, lo, hi) for v in col] for col, (lo, hi) in zip(cols, self._ranges)]).T
            out = np.array([[value_outside(v, lo, hi) for v in col] for col, (lo, hi) in zip(cols, self._ranges)]).T
            for a, v in ((self._un, un), (self._ex, ex), (self._out, out)):
                a[:L] = a[cap : cap + L] = v
        for c, net in enumerate(self._nets):  # a member with a shorter memory runs on from its own max_lag
            Lc = self._lags[c]
            self._ynk[c, :Lc] = self._ynk[c, cap : cap + Lc] = yn[:Lc]
            for k in range(Lc, L):
                self._ynk[c, k] = self._ynk[c, k + cap] = net.yn(self._un, self._ynk[c], k + cap)
        self._j, self.steps = L, 0

    def _write_u(self, u: NDArray[np.float64], un: NDArray[np.float64] | float) -> None:
        p, q = self._j % self._cap, self._j % self._cap + self._cap
        self._un[p] = self._un[q] = un
        for j, (lo, hi) in enumerate(self._ranges[:-1]):
            v = float(u[j])
            self._ex[p, j] = self._ex[q, j] = value_excess(v, lo, hi)
            self._out[p, j] = self._out[q, j] = value_outside(v, lo, hi)

    def _write_y(self, y: float) -> None:
        p, q, j = self._j % self._cap, self._j % self._cap + self._cap, len(self._ranges) - 1
        lo, hi = self._ranges[j]
        self._ex[p, j] = self._ex[q, j] = value_excess(y, lo, hi)
        self._out[p, j] = self._out[q, j] = value_outside(y, lo, hi)

    def advance(self, u: NDArray[np.float64], un: NDArray[np.float64] | float, q: float | None) -> Step:
        """The next instant from its input ``u`` (n_inputs,) (``un``: normalised; a number for one input), its
        band's quantile ``q`` (None: no band)."""
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
        rows = n - self._rlags  # the regressors' samples (the output's: the run's own past outputs)
        inside = not bool(self._out[rows, self._rcols].any())
        lower = upper = None
        if q is not None:
            width = self._scale
            if K > 1:  # the members' standard deviation (population, as numpy's std)
                mean = sum(outs) / K
                width += math.sqrt(sum((v - mean) ** 2 for v in outs) / K)
            if self._beyond > 0.0:
                width += self._beyond * (float(self._ex[rows, self._rcols].max(initial=0.0)) * self._y_half)
            half = q * width
            lower, upper = y - half, y + half
        self._write_y(y)
        self._j += 1
        self.steps += 1
        return Step(y, lower, upper, inside)
