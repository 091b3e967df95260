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

from streamid.model.domain import outside_share
from streamid.model.uncertainty import interval_report
from streamid.engine.validation import CorrelationTest, correlation_tests, r2
from streamid.errors import DataError

__all__ = ["ValidationSummary", "r2_or_nan", "summarise"]


@dataclass(frozen=True, eq=False)
class ValidationSummary:
    """R^2 figures, the validation-part predictions and the correlation tests."""

    metrics: dict[str, float]
    osa_val: np.ndarray
    fr_val: np.ndarray
    tests: tuple[CorrelationTest, ...] = field(default=())

    @property
    def finite(self) -> bool:
        """Whether every figure and prediction is finite (a model is never published otherwise)."""
        return (
            all(math.isfinite(v) for v in self.metrics.values())
            and bool(np.isfinite(self.osa_val).all())
            and bool(np.isfinite(self.fr_val).all())
        )


def r2_or_nan(y: np.ndarray, yhat: np.ndarray) -> float:
    """R^2, NaN where it is undefined (a non-finite prediction, a constant output)."""
    try:
        return r2(y, yhat)
    except DataError:  # non-finite prediction (a diverging free run) or constant output
        return float("nan")


def summarise(
    model: Any, u_est: np.ndarray, y_est: np.ndarray, u_val: np.ndarray, y_val: np.ndarray, *, corr_lags: int = 20
) -> ValidationSummary:
    """Validation figures of ``model`` (an :class:`~streamid.model.Model`) on one window."""
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        osa_e = model.predict_osa(u_est, y_est)
        osa_v = model.predict_osa(u_val, y_val)
        fr_e, fr_v = model.simulate_many([(u_est, y_est[:L]), (u_val, y_val[:L])])  # one recursion for both
    metrics = {
        "r2_osa_est": r2_or_nan(y_est[L:], osa_e[L:]),
        "r2_fr_est": r2_or_nan(y_est[L:], fr_e[L:]),
        "r2_osa_val": r2_or_nan(y_val[L:], osa_v[L:]),
        "r2_fr_val": r2_or_nan(y_val[L:], fr_v[L:]),
        "outside_domain_val": outside_share(model, u_val, y_val),  # the share outside the estimation domain
    }
    band = interval_report(model, u_val, y_val, free_run=fr_v)  # its interval on the held-out part (None: none)
    if band is not None:
        metrics["interval_coverage_val"] = band["coverage"]
    tests: tuple[CorrelationTest, ...] = ()
    if np.isfinite(osa_v).all():
        rep = correlation_tests(y_val[L:] - osa_v[L:], u_val[L:], corr_lags, input_names=model.input_names)
        metrics["correlation_fraction_inside"] = float(np.mean([t.fraction_inside for t in rep.tests]))
        metrics["correlation_tests_passed"] = float(sum(t.passed for t in rep.tests))
        tests = tuple(rep.tests)
    return ValidationSummary(metrics, osa_v, fr_v, tests)
