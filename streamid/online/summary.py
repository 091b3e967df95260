"""Validation figures of a model on one window, in the form the daemon publishes and draws.

The figures are the engine's (:mod:`streamid.engine.validation`, the same as
``streamid identify`` reports): one-step-ahead (OSA) and free-run (FR) R^2 on
the estimation and validation parts of the window, over ``t >= max_lag``, free
runs started from the first ``max_lag`` measured samples of each part; and the
five residual correlation tests of the OSA residual of the validation part,
with their ±1.96/sqrt(N) band.  The daemon keeps the validation-part
predictions to draw them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from streamid.engine.validation import correlation_tests, r2
from streamid.errors import DataError

__all__ = ["CorrelationCurve", "ValidationSummary", "summarise"]

#: Engine test names for the first input -> the daemon's short keys.
_TEST_KEYS = {"ee": "ee", "ue[0]": "ue", "e_eu[0]": "e_eu", "u2_e[0]": "u2_e", "u2_e2[0]": "u2_e2"}


@dataclass(frozen=True)
class CorrelationCurve:
    """One correlation test of the first input, ready to draw."""

    name: str
    label: str
    lags: np.ndarray
    values: np.ndarray
    band: float


@dataclass(frozen=True, eq=False)
class ValidationSummary:
    """R^2 figures, the validation-part predictions and the correlation tests."""

    metrics: dict[str, float]
    osa_val: np.ndarray
    fr_val: np.ndarray
    tests: tuple[CorrelationCurve, ...] = field(default=())

    @property
    def finite(self) -> bool:
        """Whether every figure and prediction is finite (a model is never published otherwise)."""
        return (
            all(math.isfinite(v) for v in self.metrics.values())
            and bool(np.isfinite(self.osa_val).all())
            and bool(np.isfinite(self.fr_val).all())
        )


def _r2(y: np.ndarray, yhat: np.ndarray) -> float:
    try:
        return r2(y, yhat)
    except DataError:  # non-finite prediction (a diverging free run) or constant output
        return float("nan")


def summarise(
    model: Any, u_est: np.ndarray, y_est: np.ndarray, u_val: np.ndarray, y_val: np.ndarray, *, corr_lags: int = 20
) -> ValidationSummary:
    """Validation figures of ``model`` (an :class:`~streamid.engine.Model`) on one window."""
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        osa_e = model.predict_osa(u_est, y_est)
        osa_v = model.predict_osa(u_val, y_val)
        fr_e, fr_v = model.simulate_many([(u_est, y_est[:L]), (u_val, y_val[:L])])  # one recursion for both
    metrics = {
        "r2_osa_est": _r2(y_est[L:], osa_e[L:]),
        "r2_fr_est": _r2(y_est[L:], fr_e[L:]),
        "r2_osa_val": _r2(y_val[L:], osa_v[L:]),
        "r2_fr_val": _r2(y_val[L:], fr_v[L:]),
    }
    curves: list[CorrelationCurve] = []
    if np.isfinite(osa_v).all():
        rep = correlation_tests(y_val[L:] - osa_v[L:], u_val[L:], corr_lags)
        metrics["correlation_fraction_inside"] = float(np.mean([t.fraction_inside for t in rep.tests]))
        metrics["correlation_tests_passed"] = float(sum(t.passed for t in rep.tests))
        for t in rep.tests:
            key = _TEST_KEYS.get(t.name)
            if key is not None:
                curves.append(CorrelationCurve(key, t.formula, np.asarray(t.lags), np.asarray(t.values), t.band))
    return ValidationSummary(metrics, osa_v, fr_v, tuple(curves))
