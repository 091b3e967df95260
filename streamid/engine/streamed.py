r"""A model judged on a record that arrives a piece at a time: :func:`~streamid.engine.validation.assess`'s report
in memory bounded by the chunk, not the record (``streamid validate`` on a long file; no I/O here).

:class:`StreamedRecord` takes the record's rows in any pieces (:meth:`~StreamedRecord.feed`), cuts them into the
pieces :func:`~streamid.engine.validation.assess` makes (:data:`~streamid.model.limits.CHUNK_ROWS` samples from the
record's first), and for each piece computes what ``assess`` computes for it, with the same code: the free run
carried from the previous piece (:class:`~streamid.model.freerun.RunCarry`), the one-step prediction from the
previous ``max_lag`` samples (a tail is kept), the interval's band, the domain flags, the divergence. Those
figures are the same bits as ``assess``'s; what ``assess`` computes from the whole record is merged from pieces:

* ``sum (y - mean y)^2``: each piece's count, mean and sum of squares about it merged pairwise (Chan, Golub and
  LeVeque's update), so the mean need not be known before the end (:class:`Moments`);
* the five correlation tests (:class:`LaggedSums`): per lag the raw lagged cross-product sums of the two
  sequences shifted by a provisional offset (their first piece's mean: no cancellation), every pair counted when
  its later sample arrives (a tail of the previous ``max_lag`` samples), the sums, the sums of squares and the
  first and last ``max_lag + 1`` samples of each sequence; centred at the end algebraically::

      sum_t (a_t - ma)(b_{t+tau} - mb) = S(tau) - db SA(tau) - da SB(tau) + (n - |tau|) da db

  with ``da = ma - offset``, ``SA(tau)`` the sum of the shifted ``a`` over the samples the lag uses (the total
  less the first or last ``|tau|``);
* the caveats' figures: each signal's least, greatest and samples beyond the model's range, and the second-order
  ARX fit's least squares (:class:`ArxSums`: the triangular factor of its regressors, merged piece by piece).

Equal to ``assess``'s report within rounding (tests/test_validate_streamed.py: 1e-9 relative for R^2, RMSE and
the band's width, exactly for the counts, 1e-9 absolute for the correlations).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.choice.longlinear import dense_regressors
from streamid.engine.correlation import _dot, correlation_report, tested_lags
from streamid.engine.validation import RecordReport, diverged_at
from streamid.errors import DataError
from streamid.model.domain import domain_regressors, outside
from streamid.model.freerun import RunCarry
from streamid.model.limits import CHUNK_ROWS
from streamid.model.regressors import regressor_columns
from streamid.model.uncertainty import DEFAULT_LEVEL, coverage_figures

__all__ = ["ArxSums", "LaggedSums", "Moments", "StreamedRecord"]


class Moments:
    """Count, mean and sum of squared deviations of a sequence given in pieces (Chan et al.'s pairwise merge)."""

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, 0.0, 0.0

    def add(self, x: NDArray[np.float64]) -> None:
        k = int(x.shape[0])
        if not k:
            return
        mk = float(np.mean(x))
        d = x - mk
        m2k = _dot(d, d)
        n = self.n + k
        delta = mk - self.mean
        self.mean += delta * k / n
        self.m2 += m2k + delta * delta * self.n * k / n
        self.n = n


class LaggedSums:
    """The normalised cross-correlation ``phi_ab(tau)`` (:func:`~streamid.engine.correlation.ccf`) of two sequences
    given in aligned pieces, at ``lags`` (see the module docstring): memory of ``max |tau| + 1`` samples."""

    def __init__(self, lags: NDArray[np.int64]) -> None:
        self.lags = [int(t) for t in lags]
        self.h = max(abs(t) for t in self.lags)
        self.n = 0
        self.off: tuple[float, float] | None = None
        self.s = np.zeros(len(self.lags))
        self.sa = self.sb = self.qa = self.qb = 0.0
        self.first_a, self.first_b = np.empty(0), np.empty(0)
        self.tail_a, self.tail_b = np.empty(0), np.empty(0)
        self.lo, self.hi = [np.inf, np.inf], [-np.inf, -np.inf]  # each sequence's least and greatest (a constant's 0)

    def add(self, a: NDArray[np.float64], b: NDArray[np.float64]) -> None:
        m = int(a.shape[0])
        if not m:
            return
        if self.off is None:
            self.off = (float(np.mean(a)), float(np.mean(b)))
        for i, x in enumerate((a, b)):
            self.lo[i], self.hi[i] = min(self.lo[i], float(np.min(x))), max(self.hi[i], float(np.max(x)))
        a, b = a - self.off[0], b - self.off[1]
        h, n0 = self.tail_a.shape[0], self.n
        A, B = np.concatenate([self.tail_a, a]), np.concatenate([self.tail_b, b])
        for i, tau in enumerate(self.lags):  # every pair (t, t + tau) whose later sample is in this piece
            if tau >= 0:
                j0 = max(n0, tau)  # the later sample t + tau, from j0 to n0 + m
                self.s[i] += _dot(A[j0 - tau - n0 + h : n0 + m - tau - n0 + h], B[j0 - n0 + h :])
            else:
                t0 = max(n0, -tau)  # the later sample t
                self.s[i] += _dot(A[t0 - n0 + h :], B[t0 + tau - n0 + h : n0 + m + tau - n0 + h])
        self.sa += float(np.sum(a))
        self.sb += float(np.sum(b))
        self.qa += _dot(a, a)
        self.qb += _dot(b, b)
        if self.first_a.shape[0] <= self.h:
            self.first_a = np.concatenate([self.first_a, a[: self.h + 1]])[: self.h + 1]
            self.first_b = np.concatenate([self.first_b, b[: self.h + 1]])[: self.h + 1]
        self.tail_a, self.tail_b = A[A.shape[0] - min(self.h, A.shape[0]) :].copy(), B[B.shape[0] - min(
            self.h, B.shape[0]) :].copy()
        self.n += m

    def values(self) -> NDArray[np.float64]:
        n = self.n
        out = np.zeros(len(self.lags))
        if n <= self.h + 1:
            raise DataError(f"a streamed correlation needs more than {self.h + 1} samples; got {n}")
        da, db = self.sa / n, self.sb / n
        va = 0.0 if self.lo[0] == self.hi[0] else self.qa - self.sa * da
        vb = 0.0 if self.lo[1] == self.hi[1] else self.qb - self.sb * db
        den = np.sqrt(va * vb)
        if den == 0.0:
            return out
        for i, tau in enumerate(self.lags):
            p, q = max(0, -tau), max(0, tau)  # a's first p and last q samples are not used at this lag; b's q and p
            sa = self.sa - float(np.sum(self.first_a[:p])) - float(np.sum(self.tail_a[self.tail_a.shape[0] - q :]))
            sb = self.sb - float(np.sum(self.first_b[:q])) - float(np.sum(self.tail_b[self.tail_b.shape[0] - p :]))
            out[i] = (self.s[i] - db * sa - da * sb + (n - abs(tau)) * da * db) / den
        return out


class ArxSums:
    """The least squares of :func:`~streamid.engine.choice.caveats.arx_pole_radius`'s second-order ARX fit of a
    record given in pieces: the triangular factor of ``[X | y]`` merged piece by piece (``R`` of ``[R; X_piece]``)."""

    ORDER = 2

    def __init__(self, n_inputs: int) -> None:
        self.regs = dense_regressors(self.ORDER, n_inputs, direct=False)
        self.r: NDArray[np.float64] = np.zeros((0, len(self.regs) + 2))
        self.rows = 0

    def add(self, u_ext: NDArray[np.float64], y_ext: NDArray[np.float64], first: int) -> None:
        """The rows of ``u_ext``/``y_ext`` from ``first`` (at least :attr:`ORDER`) on, their past before it."""
        k = self.ORDER
        if y_ext.shape[0] <= first:
            return
        X = regressor_columns(self.regs, u_ext[first - k :], y_ext[first - k :], k)
        block = np.column_stack([X, np.ones(X.shape[0]), y_ext[first:]])
        self.r = np.asarray(np.linalg.qr(np.vstack([self.r, block]), mode="r"))
        self.rows += X.shape[0]

    def radius(self) -> float:
        k = len(self.regs) + 1
        if self.rows < 4 * k:
            return float("nan")
        coef = np.linalg.lstsq(self.r[:k, :k], self.r[:k, k], rcond=None)[0]
        a = [c for c, r in zip(coef, self.regs) if r.signal == "y"]
        return float(np.max(np.abs(np.roots(np.concatenate([[1.0], -np.asarray(a)])))))


class StreamedRecord:
    """:func:`~streamid.engine.validation.assess`'s report on a record given a piece at a time (module docstring).

    :meth:`feed` rows in any pieces; :attr:`started` tells whether a piece was judged (the record is longer than
    one chunk); :meth:`report` at the end. ``max_lag`` the correlation tests' largest lag (``assess``'s);
    ``threads`` an ensemble's members in that many threads (the same figures).
    """

    def __init__(self, model: Any, max_lag: int = 20, threads: int = 1, step: int = CHUNK_ROWS) -> None:
        self.model, self.max_lag, self.threads = model, int(max_lag), threads
        self.L = int(model.max_lag)
        self.step = max(int(step), self.L + 1)  # assess's pieces
        self.keep = max(self.L, ArxSums.ORDER)  # the rows kept from one piece for the next
        self.buf_u: list[NDArray[np.float64]] = []
        self.buf_y: list[NDArray[np.float64]] = []
        self.buffered = 0
        self.tail_u = np.empty((0, model.n_inputs))
        self.tail_y = np.empty(0)
        self.carry: RunCarry | None = None
        self.a = 0
        self.interval = getattr(model, "interval", None)
        self.regs = domain_regressors(model)
        self.moments = Moments()
        self.sse_osa = self.sse_fr = self.width_sum = self.spread_sum = self.beyond_sum = 0.0
        self.inside = self.outside_n = 0
        self.diverged: int | None = None
        self.y_first: Any = 0.0
        lags = tested_lags(self.max_lag)
        self.pairs: dict[tuple[str, int | None], LaggedSums] = {("ee", None): LaggedSums(lags["ee"])}
        for i in range(model.n_inputs):
            self.pairs.update({(k, i): LaggedSums(lags[k]) for k in ("ue", "e_eu", "u2_e", "u2_e2")})
        self.last_e: NDArray[np.float64] = np.empty(0)  # the residual before the piece (e_eu's lag of one)
        n_sig = model.n_inputs + 1
        self.lows, self.highs, self.beyond = [np.inf] * n_sig, [-np.inf] * n_sig, [0] * n_sig
        self.arx = ArxSums(model.n_inputs)

    @property
    def started(self) -> bool:
        return self.carry is not None

    def feed(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> None:
        """The record's next rows, ``u`` (rows, n_inputs), ``y`` (rows,): a piece is judged once more rows follow it."""
        self.buf_u.append(u)
        self.buf_y.append(y)
        self.buffered += int(y.shape[0])
        if self.buffered > self.step:
            uu, yy = np.concatenate(self.buf_u), np.concatenate(self.buf_y)
            k = 0
            while self.buffered - k > self.step:
                self._piece(uu[k : k + self.step], yy[k : k + self.step])
                k += self.step
            self.buf_u, self.buf_y, self.buffered = [uu[k:].copy()], [yy[k:].copy()], self.buffered - k

    def finish(self) -> None:
        """Judge the rows still held (the record's last piece)."""
        if self.buffered:
            self._piece(np.concatenate(self.buf_u), np.concatenate(self.buf_y))
            self.buf_u, self.buf_y, self.buffered = [], [], 0

    def _piece(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> None:
        model, L, a = self.model, self.L, self.a
        h = self.tail_y.shape[0]
        u_ext, y_ext = np.concatenate([self.tail_u, u]), np.concatenate([self.tail_y, y])
        if self.carry is None:
            self.carry = RunCarry(model, y[:L], self.threads)
        hl = min(h, L)  # the rows before the piece the free run reads
        _, paths, centre, far = self.carry.next(u_ext[h - hl :], self.interval is not None)
        b = a + paths.shape[1]
        s = max(a, L)  # the piece's first scored sample
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging free run is reported (fr None)
            d = diverged_at(centre)
            self.diverged = a + d if self.diverged is None and d is not None else self.diverged
            if s < b:
                ys = y[s - a :]
                osa = model.predict_osa(u_ext[s - L - a + h :], y_ext[s - L - a + h :], threads=self.threads)[L:]
                if not np.all(np.isfinite(osa)):
                    raise DataError("r2 needs finite values (no NaN or inf)")
                e = np.subtract(ys, osa)
                self.sse_osa += float(np.sum(e**2))
                self.moments.add(ys)
                self.y_first = ys[0] if a == 0 else self.y_first
                self.sse_fr += float(np.sum((ys - centre[s - a :]) ** 2))
                self._correlations(e, u[s - a :])
                flags = outside(model.normalisation, self.regs, u_ext, y_ext)[s - a + h :]
                self.outside_n += int(np.count_nonzero(flags))
            if self.interval is not None:
                bd = self.interval.band(centre, paths, DEFAULT_LEVEL, L if a == 0 else 0, far)
                lo, hi = bd.lower[s - a :], bd.upper[s - a :]
                self.inside += int(np.count_nonzero((y[s - a :] >= lo) & (y[s - a :] <= hi)))
                self.width_sum += float(np.sum(hi - lo))
                spread, past = self.interval.terms(paths, far)  # what makes it wide (coverage_figures' parts)
                self.spread_sum += float(np.sum(spread[s - a :]))
                self.beyond_sum += 0.0 if past is None else float(np.sum(past[s - a :]))
        self._ranges(u, y)
        self.arx.add(u_ext, y_ext, max(h, ArxSums.ORDER))
        self.tail_u, self.tail_y = u_ext[u_ext.shape[0] - self.keep :], y_ext[y_ext.shape[0] - self.keep :]
        self.a = b

    def _correlations(self, e: NDArray[np.float64], u: NDArray[np.float64]) -> None:
        """The tests' sums of the residual ``e`` and the inputs ``u`` at the same samples (``assess``'s ``u[L:]``)."""
        self.pairs[("ee", None)].add(e, e)
        e2 = e * e
        prev = np.concatenate([self.last_e, e[:-1]])  # e_eu: e(k) against e(k+1) u(k+1), k from 0
        first = 1 - self.last_e.shape[0]  # the record's first residual has no predecessor: its piece starts at 1
        for i in range(u.shape[1]):
            ui = u[:, i]
            u2 = ui * ui
            self.pairs[("ue", i)].add(ui, e)
            self.pairs[("e_eu", i)].add(prev, (e * ui)[first:])
            self.pairs[("u2_e", i)].add(u2, e)
            self.pairs[("u2_e2", i)].add(u2, e2)
        self.last_e = e[-1:].copy()

    def _ranges(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> None:
        nm = self.model.normalisation
        for j, (x, lo, hi) in enumerate([*((u[:, i], nm.u_low[i], nm.u_high[i]) for i in range(u.shape[1])),
                                         (y, nm.y_low, nm.y_high)]):
            self.lows[j], self.highs[j] = min(self.lows[j], float(np.min(x))), max(self.highs[j], float(np.max(x)))
            self.beyond[j] += int(np.count_nonzero((x < float(lo)) | (x > float(hi))))

    def ranges(self) -> list[tuple[float, float, int]]:
        """Each input's then the output's ``(least, greatest, samples beyond the model's range)`` over the record."""
        return list(zip(self.lows, self.highs, self.beyond))

    def report(self) -> RecordReport:
        """The report (after :meth:`finish`): :func:`~streamid.engine.validation.assess`'s figures."""
        n, L = self.a, self.L
        m = n - L
        ss = self.moments.m2
        if ss == 0.0:
            raise DataError(f"r2 is undefined for a constant measured signal (all values {self.y_first!r})")
        with np.errstate(over="ignore", invalid="ignore"):
            fr_r2 = None if self.diverged is not None else 1.0 - self.sse_fr / ss
            rmse_fr = float(np.sqrt(self.sse_fr / m))
        figures = None
        if self.interval is not None:
            figures = {"level": float(DEFAULT_LEVEL),
                       **coverage_figures(self.inside / m, self.width_sum / m, float(np.sqrt(ss / m)),
                                          (self.interval.scale, self.spread_sum / m, self.beyond_sum / m))}
        values = {k: p.values() for k, p in self.pairs.items()}
        corr = correlation_report(m, self.max_lag, self.model.n_inputs, self.model.input_names, values)
        return RecordReport(
            n=n, n_scored=m, osa=1.0 - self.sse_osa / ss, fr=fr_r2, rmse_osa=float(np.sqrt(self.sse_osa / m)),
            rmse_fr=rmse_fr if np.isfinite(rmse_fr) else None, correlation=corr, fr_diverged_at=self.diverged,
            interval=figures, outside_domain=self.outside_n / m if m else 0.0)
