r"""Model validation: R^2 (paper eq. 4) and the five residual correlation tests (eqs. 5-6).

Correlation tests
-----------------
With the normalised cross-correlation of the paper (eq. 6)::

    phi_ab(tau) = sum_{t=1}^{N-tau} (a(t) - mean a)(b(t+tau) - mean b)
                  / sqrt(sum_t (a(t) - mean a)^2 * sum_t (b(t) - mean b)^2)

(and ``phi_ab(-tau) = phi_ba(tau)`` for negative lags), a model is adequate when
(Billings & Voon, the paper's ref. [37], eq. 5)::

    phi_ee(tau)        = delta(tau)        tested at tau = 1 .. max_lag
    phi_ue(tau)        = 0                 tau = -max_lag .. max_lag
    phi_e(eu)(tau)     = 0, tau >= 0       tau = 0 .. max_lag, (eu)(t) = e(t+1) u(t+1)
    phi_(u^2)'e(tau)   = 0                 tau = -max_lag .. max_lag, (u^2)'(t) = u(t)^2 - mean(u)^2
    phi_(u^2)'e^2(tau) = 0                 tau = -max_lag .. max_lag

each within the 95 % band ``+-1.96 / sqrt(N)``.

Names
-----
streamid calls the tests, everywhere (CLI, ``watch``, Rerun, JSON, docs; see
:data:`TESTS`): ``ee``, ``ue``, ``e_eu``, ``u2_e``, ``u2_e2``.  With several
inputs the input tests carry the input's name: ``ue[velocity]``.

streamid reports, per test (and
per input for the input tests), the values, the fraction of the tested lags
inside the band, and ``passed`` = at least 95 % of them inside (a white
residual leaves about 5 % outside by chance) *and* none outside the 99.9 % band
``+-3.29 / sqrt(N)`` (so that one strong correlation at a single lag, a missed
term, is not excused by the 5 % allowance; a white residual exceeds it at one of
41 lags in about 4 % of cases).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model.domain import outside_share
from streamid.model.limits import CHUNK_ROWS
from streamid.model.regressors import as_data
from streamid.model.uncertainty import interval_report
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

#: A test passes when at least this fraction of its lags lies inside the 95 % band...
PASS_FRACTION = 0.95
#: ...and no lag lies outside +-STRICT_Z / sqrt(N) (the 99.9 % band).
STRICT_Z = 3.29


#: The five correlation tests: canonical name -> (formula, what a failure suggests).
#: ``e`` is the one-step-ahead residual, ``u`` an input.
TESTS: dict[str, tuple[str, str]] = {
    "ee": ("φ_ee(τ) = δ(τ)", "the residual is correlated with its own past: unmodelled dynamics or coloured noise"),
    "ue": ("φ_ue(τ) = 0", "the input is correlated with the residual: an input term (or lag) is missing"),
    "e_eu": ("φ_e(eu)(τ) = 0, τ ≥ 0", "residual x input is predictable from the residual: a missing output-input cross term"),
    "u2_e": ("φ_(u²)'e(τ) = 0", "the squared input explains the residual: a missing even nonlinearity of the input"),
    "u2_e2": ("φ_(u²)'e²(τ) = 0", "the squared input explains the residual's size: a missing nonlinear input term"),
}


def correlation_test_name(kind: str, input_name: str | None = None) -> str:
    """The name of a correlation test: ``kind`` (one of :data:`TESTS`), with ``[input]`` when given."""
    if kind not in TESTS:
        raise DataError(f"correlation test must be one of {list(TESTS)}; got {kind!r}")
    return kind if input_name is None or kind == "ee" else f"{kind}[{input_name}]"


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


def ccf(a: NDArray[np.float64], b: NDArray[np.float64], lags: NDArray[np.int64]) -> NDArray[np.float64]:
    """Normalised cross-correlation ``phi_ab(tau)`` of eq. (6) at the given lags (may be negative).

    A constant sequence has no correlation: its values are 0.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    n = a.size
    da, db = a - a.mean(), b - b.mean()
    den = np.sqrt(float(da @ da) * float(db @ db))
    out = np.zeros(len(lags))
    if den == 0.0:
        return out
    for i, tau in enumerate(lags):
        t = int(tau)
        if abs(t) >= n:
            continue
        out[i] = (da[: n - t] @ db[t:]) / den if t >= 0 else (db[: n + t] @ da[-t:]) / den
    return out


#: A test's sequence by ranges: ``part(a, b)`` its samples ``a..b-1``, made on demand (one chunk held, not the record)
Part = Callable[[int, int], NDArray[np.float64]]


def streamed_ccf(a: Part, b: Part, n: int, lags: NDArray[np.int64], chunk: int | None = None) -> NDArray[np.float64]:
    """:func:`ccf` of two sequences of ``n`` samples given by ranges, ``chunk`` rows at a time (default ``CHUNK_ROWS``):
    means, variances, then the lagged cross-products accumulated chunk by chunk, each chunk of ``a`` against the part
    of ``b`` its lags reach (the overlap). :func:`ccf`'s values to rounding (to the bit in one chunk)."""
    step = int(CHUNK_ROWS if chunk is None else chunk)
    spans = [(s, min(n, s + step)) for s in range(0, n, step)]
    ma = sum(float(np.sum(a(s, e))) for s, e in spans) / n
    mb = sum(float(np.sum(b(s, e))) for s, e in spans) / n
    va = sum(float(np.dot(d := a(s, e) - ma, d)) for s, e in spans)
    vb = sum(float(np.dot(d := b(s, e) - mb, d)) for s, e in spans)
    den = np.sqrt(va * vb)
    out = np.zeros(len(lags))
    if den == 0.0:
        return out
    lo, hi = min(0, int(np.min(lags))), max(0, int(np.max(lags)))
    acc = np.zeros(len(lags))
    for s, e in spans:  # sum over t in [s, e) of da[t] db[t + tau], 0 <= t + tau < n
        da = a(s, e) - ma
        w0, w1 = max(0, s + lo), min(n, e + hi)
        db = b(w0, w1) - mb
        for i, tau in enumerate(lags):
            t = int(tau)
            t0, t1 = max(s, -t), min(e, n - t)  # the rows of this chunk whose partner is in the record
            if t1 > t0:
                acc[i] += float(da[t0 - s : t1 - s] @ db[t0 + t - w0 : t1 + t - w0])
    for i, tau in enumerate(lags):
        if abs(int(tau)) < n:
            out[i] = acc[i] / den
    return out


def _piece(x: NDArray[np.float64], times: NDArray[np.float64] | None, shift: int, power: int, minus: float, a: int,
           b: int) -> NDArray[np.float64]:
    """Samples ``a..b-1`` of ``x(t + shift) ** power (* times(t + shift)) - minus`` (a correlation test's sequence)."""
    p = x[a + shift : b + shift] ** power  # (x ** 1 and - 0.0 leave every value as it was)
    return (p if times is None else p * times[a + shift : b + shift]) - minus


@dataclass(frozen=True)
class CorrelationTest:
    """One correlation test: its lags, values, band, fraction inside and verdict."""

    name: str
    formula: str
    lags: tuple[int, ...]
    values: tuple[float, ...]
    band: float

    @property
    def fraction_inside(self) -> float:
        v = np.abs(np.asarray(self.values))
        return float(np.mean(v <= self.band)) if v.size else 1.0

    @property
    def strict_band(self) -> float:
        """The 99.9 % band ``STRICT_Z / sqrt(N)`` (``band`` is ``1.96 / sqrt(N)``)."""
        return self.band * STRICT_Z / 1.96

    @property
    def passed(self) -> bool:
        return bool(self.fraction_inside >= PASS_FRACTION and self.max_abs <= self.strict_band)

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.values))) if self.values else 0.0

    @property
    def kind(self) -> str:
        """The test without its input: ``ue`` for ``ue[velocity]``."""
        return self.name.split("[", 1)[0]

    def worst(self) -> tuple[int, float]:
        """``(lag, value)`` of the largest ``|value|`` (``(0, 0.0)`` when there are no lags)."""
        if not self.values:
            return 0, 0.0
        i = int(np.argmax(np.abs(self.values)))
        return int(self.lags[i]), float(self.values[i])

    @property
    def reason(self) -> str:
        """Why the test failed, naming the lag, its value and the band it left (``""`` when it passed)."""
        if self.passed:
            return ""
        lag, value = self.worst()
        if abs(value) > self.strict_band:
            return f"lag {lag} value {value:.3g} outside ±{self.strict_band:.3g} (99.9 % band)"
        v = np.abs(np.asarray(self.values))
        out = int(np.sum(v > self.band))
        return (
            f"{out} of {v.size} lags outside ±{self.band:.3g} (95 % band, at most {100 * (1 - PASS_FRACTION):.0f} % may be), "
            f"largest at lag {lag} value {value:.3g}"
        )

    def verdict(self) -> str:
        """One line: ``ee pass (20/20 lags inside ±0.0877)`` or ``ue FAIL: lag 3 value 0.21 outside ±0.147 ...``."""
        if self.passed:
            v = np.abs(np.asarray(self.values))
            return f"{self.name} pass ({int(np.sum(v <= self.band))}/{v.size} lags inside ±{self.band:.3g})"
        return f"{self.name} FAIL: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "formula": self.formula,
            "lags": list(self.lags),
            "values": [float(v) for v in self.values],
            "band": self.band,
            "strict_band": self.strict_band,
            "fraction_inside": self.fraction_inside,
            "max_abs": self.max_abs,
            "passed": self.passed,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class CorrelationReport:
    """The five tests (input tests once per input)."""

    n: int
    band: float
    tests: tuple[CorrelationTest, ...]

    @property
    def passed(self) -> bool:
        return all(t.passed for t in self.tests)

    def __getitem__(self, name: str) -> CorrelationTest:
        for t in self.tests:
            if t.name == name:
                return t
        raise KeyError(f"no correlation test {name!r}; tests: {[t.name for t in self.tests]}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "n": self.n,
            "band": self.band,
            "pass_rule": (
                f"fraction of lags inside +-1.96/sqrt(N) >= {PASS_FRACTION} and none outside +-{STRICT_Z}/sqrt(N)"
            ),
            "passed": self.passed,
            "tests": {t.name: t.to_dict() for t in self.tests},
        }


def correlation_tests(
    residual: ArrayLike, u: ArrayLike, max_lag: int = 20, input_names: tuple[str, ...] | list[str] | None = None
) -> CorrelationReport:
    """The five correlation tests of eq. (5) on a residual and the inputs at the same times.

    Parameters
    ----------
    residual : array_like, shape (N,)
        Model residual ``e(t) = y(t) - yhat(t)`` (normally one-step-ahead).
    u : array_like, shape (N,) or (N, n_inputs)
        Inputs at the same time instants.
    max_lag : int
        Largest lag tested (default 20).
    input_names : sequence of str, optional
        Names of the inputs (default ``u0``, ``u1``, ...), used in the test names when there are several.

    Returns
    -------
    CorrelationReport
        Test names (:data:`TESTS`): ``ee``, ``ue``, ``e_eu``, ``u2_e``, ``u2_e2``; with several
        inputs the input tests once per input, named ``ue[<input name>]`` and so on.
    """
    ua, e = as_data(u, residual, min_samples=3)
    if not (isinstance(max_lag, (int, np.integer)) and max_lag >= 1):
        raise DataError(f"max_lag must be an integer >= 1; got {max_lag!r}")
    n = e.size
    L = int(min(max_lag, n - 2))
    band = float(1.96 / np.sqrt(n))
    pos = np.arange(1, L + 1)
    nonneg = np.arange(0, L + 1)
    both = np.arange(-L, L + 1)
    n_in = ua.shape[1]
    names = tuple(input_names) if input_names is not None else tuple(f"u{i}" for i in range(n_in))
    if len(names) != n_in:
        raise DataError(f"input_names must name the {n_in} input(s); got {list(names)}")

    def mk(kind: str, i: int | None, lags: NDArray[np.int64], values: NDArray[np.float64]) -> CorrelationTest:
        nm = correlation_test_name(kind, None if i is None or n_in == 1 else names[i])
        return CorrelationTest(nm, TESTS[kind][0], tuple(lags.tolist()), tuple(values.tolist()), band)

    res: Part = partial(_piece, e, None, 0, 1, 0.0)  # chunks of the residual and its products, made on demand
    tests = [mk("ee", None, pos, streamed_ccf(res, res, n, pos))]
    for i in range(n_in):
        ui, m2 = ua[:, i], float(ua[:, i].mean()) ** 2  # (eu)(t) = e(t+1) u(t+1), t < n - 1; (u^2)' = u^2 - mean(u)^2
        u2: Part = partial(_piece, ui, None, 0, 2, m2)
        tests += [
            mk("ue", i, both, streamed_ccf(partial(_piece, ui, None, 0, 1, 0.0), res, n, both)),
            mk("e_eu", i, nonneg, streamed_ccf(res, partial(_piece, e, ui, 1, 1, 0.0), n - 1, nonneg)),
            mk("u2_e", i, both, streamed_ccf(u2, res, n, both)),
            mk("u2_e2", i, both, streamed_ccf(u2, partial(_piece, e, None, 0, 2, 0.0), n, both)),
        ]
    return CorrelationReport(n, float(band), tuple(tests))


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


def _record(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], fr: NDArray[np.float64],
            max_lag: int) -> RecordReport:
    osa_r2, fr_r2, res, osa, _ = _predictions(model, u, y, fr=fr)
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        rmse_fr = float(np.sqrt(np.mean((y[L:] - fr[L:]) ** 2)))
    return RecordReport(
        n=int(y.shape[0]), n_scored=int(y.shape[0] - L), osa=osa_r2, fr=fr_r2,
        rmse_osa=float(np.sqrt(np.mean(res**2))), rmse_fr=rmse_fr if np.isfinite(rmse_fr) else None,
        correlation=correlation_tests(res, u[L:], max_lag, model.input_names),
        predictions={"osa": osa, "fr": fr}, fr_diverged_at=diverged_at(fr),
        interval=interval_report(model, u, y, free_run=fr), outside_domain=outside_share(model, u, y),
    )


def assess(model: Model, u: ArrayLike, y: ArrayLike, *, max_lag: int = 20) -> RecordReport:
    """One-step-ahead and free-run R^2, RMSE and the correlation tests of ``model`` on one record.

    The record is typically one the model has never seen (``streamid validate``; a second experiment with
    another excitation is the real test).  Pure: numbers in, a :class:`RecordReport` out.

    Raises
    ------
    DataError
        A record shorter than ``model.max_lag + 2`` samples, or inputs that do not match the model's count.
    """
    ua, ya = as_data(u, y, min_samples=model.max_lag + 2)
    if ua.shape[1] != model.n_inputs:
        raise DataError(f"the model has {model.n_inputs} input(s) {list(model.input_names)}; the data give "
                        f"{ua.shape[1]}: pass one input column per model input, in the model's order")
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging free run is reported (fr None), not warned about
        fr = model.simulate(ua, ya[: model.max_lag])
    return _record(model, ua, ya, fr, max_lag)


def prediction_r2(model: Model, u: ArrayLike, y: ArrayLike) -> tuple[float, float | None, NDArray[np.float64]]:
    """``(osa_r2, fr_r2, osa_residual)`` of a model on one data set (over ``t >= max_lag``; ``fr_r2`` None: the
    free run diverged)."""
    osa_r2, fr_r2, res, _, _ = _predictions(model, u, y)
    return osa_r2, fr_r2, res


def _predictions(
    model: Model, u: ArrayLike, y: ArrayLike, fr: NDArray[np.float64] | None = None
) -> tuple[float, float | None, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    ua, ya = as_data(u, y, min_samples=model.max_lag + 2)
    L = model.max_lag
    osa = model.predict_osa(ua, ya)
    if fr is None:
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
) -> ValidationReport:
    """OSA and free-run R^2 on estimation and validation data, and the correlation tests of both.

    Parameters
    ----------
    model : Model
    u_est, y_est, u_val, y_val : array_like
        Estimation and validation data (inputs ``(N,)`` or ``(N, n_inputs)``).
    max_lag : int
        Largest lag of the correlation tests.

    Returns
    -------
    ValidationReport
        Also carries the four prediction arrays in ``predictions``.
    """
    L = model.max_lag
    ue, ye = as_data(u_est, y_est, min_samples=L + 2)
    uv, yv = as_data(u_val, y_val, min_samples=L + 2)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging free run is reported (R^2 None), not warned about
        p_fr_e, p_fr_v = model.simulate_many([(ue, ye[:L]), (uv, yv[:L])])  # both free runs in one recursion
    e, v = _record(model, ue, ye, p_fr_e, max_lag), _record(model, uv, yv, p_fr_v, max_lag)
    return ValidationReport(
        osa_est=e.osa,
        osa_val=v.osa,
        fr_est=e.fr,
        fr_val=v.fr,
        correlation_est=e.correlation,
        correlation_val=v.correlation,
        predictions={"osa_est": e.predictions["osa"], "fr_est": p_fr_e, "osa_val": v.predictions["osa"],
                     "fr_val": p_fr_v},
        extra={"interval_val": v.interval, "outside_domain_val": v.outside_domain},
    )
