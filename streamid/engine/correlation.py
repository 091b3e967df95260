r"""The five residual correlation tests of the paper (eqs. 5-6), streamed chunk by chunk.

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
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import DataError
from streamid.model.limits import CHUNK_ROWS
from streamid.model.regressors import as_data

__all__ = ["PASS_FRACTION", "STRICT_Z", "TESTS", "CorrelationReport", "CorrelationTest", "ccf", "correlation_test_name",
           "correlation_report", "correlation_tests", "streamed_ccf", "tested_lags"]

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
    of ``b`` its lags reach (the overlap). :func:`ccf`'s values to rounding."""
    step = int(CHUNK_ROWS if chunk is None else chunk)
    spans = [(s, min(n, s + step)) for s in range(0, n, step)]
    ma = sum(float(np.sum(a(s, e))) for s, e in spans) / n
    mb = sum(float(np.sum(b(s, e))) for s, e in spans) / n
    va = sum(_dot(d := a(s, e) - ma, d) for s, e in spans)
    vb = sum(_dot(d := b(s, e) - mb, d) for s, e in spans)
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
                acc[i] += _dot(da[t0 - s : t1 - s], db[t0 + t - w0 : t1 + t - w0])
    for i, tau in enumerate(lags):
        if abs(int(tau)) < n:
            out[i] = acc[i] / den
    return out


def _dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """``a . b`` without BLAS: OpenBLAS's threaded dot waits for its second thread on every call, and on a busy
    2-core machine a million-sample record's tests took 22 s that way against 0.08 s in one thread (the streamed tests
    make ~200 dots a chunk)."""
    return float(np.einsum("i,i->", a, b))


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
    ua, e = as_data(u, residual, min_samples=3, copy=False)  # read only: no copy of a long record
    if not (isinstance(max_lag, (int, np.integer)) and max_lag >= 1):
        raise DataError(f"max_lag must be an integer >= 1; got {max_lag!r}")
    n = e.size
    L = int(min(max_lag, n - 2))
    n_in = ua.shape[1]
    lags = tested_lags(L)
    res: Part = partial(_piece, e, None, 0, 1, 0.0)  # chunks of the residual and its products, made on demand
    values: dict[tuple[str, int | None], NDArray[np.float64]] = {("ee", None): streamed_ccf(res, res, n, lags["ee"])}
    for i in range(n_in):
        ui, m2 = ua[:, i], float(ua[:, i].mean()) ** 2  # (eu)(t) = e(t+1) u(t+1), t < n - 1; (u^2)' = u^2 - mean(u)^2
        u2: Part = partial(_piece, ui, None, 0, 2, m2)
        values[("ue", i)] = streamed_ccf(partial(_piece, ui, None, 0, 1, 0.0), res, n, lags["ue"])
        values[("e_eu", i)] = streamed_ccf(res, partial(_piece, e, ui, 1, 1, 0.0), n - 1, lags["e_eu"])
        values[("u2_e", i)] = streamed_ccf(u2, res, n, lags["u2_e"])
        values[("u2_e2", i)] = streamed_ccf(u2, partial(_piece, e, None, 0, 2, 0.0), n, lags["u2_e2"])
    return correlation_report(n, L, n_in, input_names, values)


def tested_lags(max_lag: int) -> dict[str, NDArray[np.int64]]:
    """Each test's lags (:data:`TESTS`' kinds) up to ``max_lag``: ``ee`` 1..L, ``e_eu`` 0..L, the others -L..L."""
    both = np.arange(-max_lag, max_lag + 1)
    return {"ee": np.arange(1, max_lag + 1), "ue": both, "e_eu": np.arange(0, max_lag + 1), "u2_e": both,
            "u2_e2": both}


def correlation_report(n: int, max_lag: int, n_in: int, input_names: tuple[str, ...] | list[str] | None,
                       values: dict[tuple[str, int | None], NDArray[np.float64]]) -> CorrelationReport:
    """The report of the tests' ``values`` (``(kind, input index)`` -> values at :func:`tested_lags`' lags; ``ee``'s
    index None) on ``n`` residual samples (its band ``1.96 / sqrt(n)``): :func:`correlation_tests`' and the
    streamed validation's (:mod:`streamid.engine.streamed`)."""
    band = float(1.96 / np.sqrt(n))
    names = tuple(input_names) if input_names is not None else tuple(f"u{i}" for i in range(n_in))
    if len(names) != n_in:
        raise DataError(f"input_names must name the {n_in} input(s); got {list(names)}")
    lags = tested_lags(max_lag)

    def mk(kind: str, i: int | None) -> CorrelationTest:
        nm = correlation_test_name(kind, None if i is None or n_in == 1 else names[i])
        return CorrelationTest(nm, TESTS[kind][0], tuple(lags[kind].tolist()), tuple(values[(kind, i)].tolist()), band)

    tests = [mk("ee", None)]
    for i in range(n_in):
        tests += [mk(kind, i) for kind in ("ue", "e_eu", "u2_e", "u2_e2")]
    return CorrelationReport(n, float(band), tuple(tests))
