r"""Model validation: R^2 (paper eq. 4) and the five residual correlation tests (eqs. 5-6).

The five residual correlation tests (eqs. 5-6), their names and pass rule are in
:mod:`streamid.engine.correlation` (streamed chunk by chunk); their names are re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine.correlation import (PASS_FRACTION, STRICT_Z, TESTS, CorrelationReport, CorrelationTest, ccf,
                                         correlation_test_name, correlation_tests)
from streamid.model.domain import outside_share
from streamid.model.freerun import chunked_runs
from streamid.model.limits import CHUNK_ROWS
from streamid.model.regressors import as_data
from streamid.model.uncertainty import DEFAULT_LEVEL, coverage_figures
from streamid.errors import DataError

if TYPE_CHECKING:
    from streamid.model.narx import Model

__all__ = [
    "TESTS",
    "correlation_test_name",
    "r2",
    "r2_or_none",
    "diverged_at",
    "DIVERGED_ABOVE",
    "ccf",
    "correlation_tests",
    "CorrelationTest",
    "CorrelationReport",
    "ValidationReport",
    "validate",
    "RecordReport",
    "assess",
    "fit_percent",
    "PASS_FRACTION",
    "STRICT_Z",
]


def r2(y: ArrayLike, yhat: ArrayLike) -> float:
    """Multiple correlation coefficient ``1 - sum (y - yhat)^2 / sum (y - mean y)^2`` (eq. 4).

    Raises
    ------
    DataError
        If the shapes differ, values are not finite, or ``y`` is constant.
    """
    ya = np.asarray(y, dtype=np.float64).reshape(-1)
    yh = np.asarray(yhat, dtype=np.float64).reshape(-1)
    if ya.shape != yh.shape or ya.size < 2:
        raise DataError(f"r2 needs two arrays of the same length >= 2; got {np.shape(y)} and {np.shape(yhat)}")
    if not (np.all(np.isfinite(ya)) and np.all(np.isfinite(yh))):
        raise DataError("r2 needs finite values (no NaN or inf)")
    ss = float(np.sum((ya - ya.mean()) ** 2))
    if ss == 0.0:
        raise DataError(f"r2 is undefined for a constant measured signal (all values {ya[0]!r})")
    with np.errstate(over="ignore"):  # a finite but huge prediction (a diverged free run): R^2 = -inf, said once
        return 1.0 - float(np.sum((ya - yh) ** 2)) / ss


#: A free run beyond this magnitude has diverged: its squared errors would overflow a double's sums.
DIVERGED_ABOVE = 1e150


def diverged_at(sim: ArrayLike) -> int | None:
    """The first sample at which a free run has diverged (not finite, or beyond :data:`DIVERGED_ABOVE` in
    magnitude), or None."""
    a = np.asarray(sim, dtype=np.float64).reshape(-1)
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(a) <= DIVERGED_ABOVE)  # NaN compares False: counted
    return int(np.argmax(bad)) if bad.any() else None


def r2_or_none(y: ArrayLike, sim: ArrayLike) -> float | None:
    """R^2 of a free run against ``y``; None when the free run diverged (:func:`diverged_at`).

    A diverged free run has no R^2: reports show it as null and name the sample (:func:`diverged_at`)
    instead of failing the whole report (issue 37). A finite, far-off run gets its (very negative) R^2.
    """
    return None if diverged_at(sim) is not None else r2(y, sim)


@dataclass(frozen=True)
class ValidationReport:
    """R^2 of one-step-ahead and free-run predictions on estimation and validation data, plus the tests.

    R^2 is computed over ``t >= model.max_lag`` (the samples the model predicts);
    free runs start from the first ``max_lag`` measured samples of each data set.
    The correlation tests use the one-step-ahead residuals. A free run that diverged (a value not finite)
    has R^2 None (null in JSON); :meth:`diverged` names the sample.
    """

    osa_est: float
    osa_val: float
    fr_est: float | None
    fr_val: float | None
    correlation_est: CorrelationReport
    correlation_val: CorrelationReport
    extra: dict[str, Any] = field(default_factory=dict)
    #: Full-length predictions aligned with the data (first ``max_lag`` values measured):
    #: ``osa_est``, ``fr_est``, ``osa_val``, ``fr_val``. Not part of :meth:`to_dict`.
    predictions: dict[str, NDArray[np.float64]] = field(default_factory=dict, repr=False)

    def r2_dict(self) -> dict[str, float | None]:
        return {"osa_est": self.osa_est, "osa_val": self.osa_val, "fr_est": self.fr_est, "fr_val": self.fr_val}

    def diverged(self) -> dict[str, int]:
        """``{"est" | "val": first non-finite sample}`` of the free runs that diverged (empty: none did)."""
        if "diverged" in self.extra:  # validate's, found as it judged the records (with or without predictions)
            return dict(self.extra["diverged"])
        out = {}
        for part in ("est", "val"):
            k = diverged_at(self.predictions[f"fr_{part}"]) if f"fr_{part}" in self.predictions else None
            if k is not None:
                out[part] = k
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "r2": self.r2_dict(),
            "correlation": {"est": self.correlation_est.to_dict(), "val": self.correlation_val.to_dict()},
            **self.extra,
        }


def fit_percent(r2_value: float | None) -> float:
    """The normalised-RMSE fit of System Identification Toolbox users, ``100 (1 - |y - yhat| / |y - mean y|)``.

    It is ``100 (1 - sqrt(1 - R^2))``: R^2 0.99 is a fit of 90 %, 0.75 of 50 %; a prediction worse than the
    data's mean (R^2 < 0) has a negative fit, and a non-finite or absent (diverged) R^2 gives nan.
    """
    if r2_value is None or not np.isfinite(r2_value):
        return float("nan")
    return float(100.0 * (1.0 - np.sqrt(max(0.0, 1.0 - float(r2_value)))))


@dataclass(frozen=True)
class RecordReport:
    """A model on one record that was not used to fit it: :func:`assess`'s result.

    R^2 and RMSE are over ``t >= model.max_lag`` (``n_scored`` samples); the free run starts from the record's
    first ``max_lag`` measured outputs; the correlation tests use the one-step-ahead residual. A free run that
    diverged has ``fr`` None and ``fr_diverged_at`` its first non-finite sample.
    """

    n: int
    n_scored: int
    osa: float
    fr: float | None
    rmse_osa: float
    rmse_fr: float | None
    correlation: CorrelationReport
    #: full-length ``osa`` and ``fr`` predictions (the first ``max_lag`` values measured); not in :meth:`to_dict`
    predictions: dict[str, NDArray[np.float64]] = field(default_factory=dict, repr=False)
    #: the first sample at which the free run is not finite (None: it did not diverge)
    fr_diverged_at: int | None = None
    #: the model's free-run interval on the record (level, coverage, width, width_over_std); None: it carries none
    interval: dict[str, Any] | None = None
    #: the share of the scored samples at which a regressor lies outside the estimation domain
    outside_domain: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "interval": self.interval,
            "outside_domain": self.outside_domain,
            "n": self.n,
            "n_scored": self.n_scored,
            "r2": {"osa": self.osa, "fr": self.fr},
            "fr_diverged_at": self.fr_diverged_at,
            "fit_percent": {"osa": fit_percent(self.osa), "fr": None if self.fr is None else fit_percent(self.fr)},
            "rmse": {"osa": self.rmse_osa, "fr": self.rmse_fr},
            "correlation": self.correlation.to_dict(),
        }


def _record(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], max_lag: int, threads: int = 1,
            band: bool = True, keep: bool = True, osa_given: NDArray[np.float64] | None = None) -> RecordReport:
    """The report on one record, made :data:`~streamid.model.limits.CHUNK_ROWS` samples at a time: the free run
    once (:func:`~streamid.model.freerun.chunked_paths`: its R^2 and its interval's band from the same paths),
    the one-step prediction, the sums of the figures. Memory: a piece's, plus the one-step residual the
    correlation tests read (one value a sample) and, with ``keep``, the two predictions. Up to one chunk the
    figures are the whole-record formulas' to the bit (one piece); beyond it their sums are added piece by piece
    (equal to rounding). ``band`` False: without the interval's coverage and the domain's share (``validate``'s
    estimation record, whose are not reported); ``threads``: an ensemble's members in that many threads;
    ``osa_given``: the model's one-step predictions over the record, already made (not made again)."""
    L, n = model.max_lag, int(y.shape[0])
    ys = y[L:]
    mean = ys.mean()
    ss = sse_osa = sse_fr = width_sum = spread_sum = beyond_sum = 0.0
    inside, diverged = 0, None
    res = np.empty(n - L)
    osa_all, fr_all = (y.copy(), np.empty(n)) if keep else (None, None)
    interval = getattr(model, "interval", None) if band else None
    for a, paths, centre, far in chunked_runs(model, u, y[:L], CHUNK_ROWS, threads, far=interval is not None):
        b = a + paths.shape[1]
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging free run is reported (fr None)
            d = diverged_at(centre)
            diverged = a + d if diverged is None and d is not None else diverged
            s = max(a, L)  # the piece's first scored sample
            if s < b:
                osa = (model.predict_osa(u[s - L : b], y[s - L : b], threads=threads)[L:] if osa_given is None
                       else osa_given[s:b])
                if not np.all(np.isfinite(osa)):
                    raise DataError("r2 needs finite values (no NaN or inf)")
                e = res[s - L : b - L]
                np.subtract(y[s:b], osa, out=e)
                sse_osa += float(np.sum(e**2))
                ss += float(np.sum((y[s:b] - mean) ** 2))
                sse_fr += float(np.sum((y[s:b] - centre[s - a :]) ** 2))
                if osa_all is not None:
                    osa_all[s:b] = osa
            if fr_all is not None:
                fr_all[a:b] = centre
            if interval is not None:
                bd = interval.band(centre, paths, DEFAULT_LEVEL, L if a == 0 else 0, far)
                lo, hi = bd.lower[s - a :], bd.upper[s - a :]
                inside += int(np.count_nonzero((y[s:b] >= lo) & (y[s:b] <= hi)))
                width_sum += float(np.sum(hi - lo))
                spread, past = interval.terms(paths, far)  # what makes it wide (coverage_figures' parts)
                spread_sum += float(np.sum(spread[s - a :]))
                beyond_sum += 0.0 if past is None else float(np.sum(past[s - a :]))
    m = n - L
    if ss == 0.0:
        raise DataError(f"r2 is undefined for a constant measured signal (all values {ys[0]!r})")
    with np.errstate(over="ignore", invalid="ignore"):
        fr_r2 = None if diverged is not None else 1.0 - sse_fr / ss
        rmse_fr = float(np.sqrt(sse_fr / m))
    figures = None
    if interval is not None:
        figures = {"level": float(DEFAULT_LEVEL), **coverage_figures(inside / m, width_sum / m, float(np.sqrt(ss / m)),
                                                                      (interval.scale, spread_sum / m, beyond_sum / m))}
    return RecordReport(
        n=n, n_scored=m, osa=1.0 - sse_osa / ss, fr=fr_r2, rmse_osa=float(np.sqrt(sse_osa / m)),
        rmse_fr=rmse_fr if np.isfinite(rmse_fr) else None,
        correlation=correlation_tests(res, u[L:], max_lag, model.input_names),
        predictions={"osa": osa_all, "fr": fr_all} if osa_all is not None and fr_all is not None else {},
        fr_diverged_at=diverged, interval=figures, outside_domain=outside_share(model, u, y) if band else 0.0,
    )


def assess(model: Model, u: ArrayLike, y: ArrayLike, *, max_lag: int = 20, threads: int = 1,
           keep: bool = True) -> RecordReport:
    """One-step-ahead and free-run R^2, RMSE and the correlation tests of ``model`` on one record.

    The record is typically one the model has never seen (``streamid validate``; a second experiment with
    another excitation is the real test).  Pure: numbers in, a :class:`RecordReport` out. ``threads`` > 1: the
    predictions computed in that many threads (for a caller with cores to spare; the same report to the bit).
    Made a chunk of samples at a time (memory bounded by the chunk, not the record); ``keep`` False: without the
    full-length predictions (``predictions`` empty), which are what a long record would hold.

    Raises
    ------
    DataError
        A record shorter than ``model.max_lag + 2`` samples, or inputs that do not match the model's count.
    """
    ua, ya = as_data(u, y, min_samples=model.max_lag + 2, copy=False)  # read only
    if ua.shape[1] != model.n_inputs:
        raise DataError(f"the model has {model.n_inputs} input(s) {list(model.input_names)}; the data give "
                        f"{ua.shape[1]}: pass one input column per model input, in the model's order")
    return _record(model, ua, ya, max_lag, threads, keep=keep)


def prediction_r2(model: Model, u: ArrayLike, y: ArrayLike) -> tuple[float, float | None, NDArray[np.float64]]:
    """``(osa_r2, fr_r2, osa_residual)`` of a model on one data set (over ``t >= max_lag``; ``fr_r2`` None: the
    free run diverged)."""
    osa_r2, fr_r2, res, _, _ = _predictions(model, u, y)
    return osa_r2, fr_r2, res


def _predictions(
    model: Model, u: ArrayLike, y: ArrayLike
) -> tuple[float, float | None, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    ua, ya = as_data(u, y, min_samples=model.max_lag + 2)
    L = model.max_lag
    osa = model.predict_osa(ua, ya)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging free run is reported, not warned about
        fr = model.simulate(ua, ya[:L])
    return r2(ya[L:], osa[L:]), r2_or_none(ya[L:], fr[L:]), ya[L:] - osa[L:], osa, fr


def validate(
    model: Model,
    u_est: ArrayLike,
    y_est: ArrayLike,
    u_val: ArrayLike,
    y_val: ArrayLike,
    *,
    max_lag: int = 20,
    threads: int = 1,
    keep: bool = True,
    osa_predictions_est: ArrayLike | None = None,
) -> ValidationReport:
    """OSA and free-run R^2 on estimation and validation data, and the correlation tests of both.

    Parameters
    ----------
    model : Model
    u_est, y_est, u_val, y_val : array_like
        Estimation and validation data (inputs ``(N,)`` or ``(N, n_inputs)``).
    max_lag : int
        Largest lag of the correlation tests.
    threads : int
        The predictions computed in that many threads (for a caller with cores to spare; the same report to
        the bit).
    keep : bool
        Keep the four full-length predictions (``predictions``); False: the report's figures only, in memory
        bounded by the chunk (a long record's).
    osa_predictions_est : array_like, optional
        The model's one-step predictions over the estimation record, when already made (``identify``'s
        ``Result.extra["osa_predictions_est"]``): shape ``(N_est,)``, finite from sample ``max_lag`` on; used
        instead of predicting again (the same figures: up to one chunk to the bit, beyond it equal to rounding).

    Returns
    -------
    ValidationReport
        Also carries the four prediction arrays in ``predictions``.
    """
    L = model.max_lag
    ue, ye = as_data(u_est, y_est, min_samples=L + 2, copy=False)  # read only: no copy of a long record
    uv, yv = as_data(u_val, y_val, min_samples=L + 2, copy=False)
    given = None
    if osa_predictions_est is not None:
        given = np.asarray(osa_predictions_est, dtype=np.float64)
        if given.shape != ye.shape:
            raise DataError(f"osa_predictions_est must be the one-step predictions over the estimation record, "
                            f"shape {ye.shape}; got shape {given.shape}")
    e = _record(model, ue, ye, max_lag, threads, band=False, keep=keep, osa_given=given)  # band, domain: not reported
    v = _record(model, uv, yv, max_lag, threads, keep=keep)
    return ValidationReport(
        osa_est=e.osa,
        osa_val=v.osa,
        fr_est=e.fr,
        fr_val=v.fr,
        correlation_est=e.correlation,
        correlation_val=v.correlation,
        predictions={f"{k}_{part}": r.predictions[k] for part, r in (("est", e), ("val", v)) for k in ("osa", "fr")
                     if k in r.predictions},
        extra={"interval_val": v.interval, "outside_domain_val": v.outside_domain,
               "diverged": {p: r.fr_diverged_at for p, r in (("est", e), ("val", v)) if r.fr_diverged_at is not None}},
    )
