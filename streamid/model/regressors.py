"""A model's regressors (its lagged terms), input checks and the normalisation to [-1, 1].

Conventions
-----------
``u`` has shape ``(N, n_inputs)`` (a 1-D array is one input), ``y`` shape ``(N,)``.
Candidate regressors are ordered output lags first, then each input's lags::

    y(t-1) .. y(t-Ly), u_0(t-1) .. u_0(t-Lu), u_1(t-1) .. u_1(t-Lu), ...

(with ``min_lag_u = 0`` each input's run starts at its direct term ``u_i(t)``). This order is the bit order of a lag harmony and the coordinate order of a
centre. Row ``k`` of the regressor matrix (:mod:`streamid.engine.fit.lagmatrix`) is the regressor at time
``t = L + k`` where ``L = max(Ly, Lu)``; rows exist for ``t = L .. N-1``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model.limits import MIN_SPAN
from streamid.errors import DataError, ModelFormatError

__all__ = [
    "Normalisation",
    "Regressor",
    "as_data",
    "regressor_columns",
    "check_finite",
    "format_lags",
]


@dataclass(frozen=True)
class Regressor:
    """One lagged term: ``signal`` is ``"y"`` or ``"u"``, ``index`` the input number (0 for ``"y"``)."""

    signal: str
    index: int
    lag: int

    def label(self, input_names: tuple[str, ...] | None = None, output_name: str | None = None) -> str:
        """Human-readable name such as ``y(t-1)`` or ``u0(t-2)`` (or the column names)."""
        if self.signal == "y":
            name = output_name or "y"
        else:
            name = input_names[self.index] if input_names else f"u{self.index}"
        return f"{name}({_t(self.lag)})"

    def to_dict(self) -> dict[str, Any]:
        return {"signal": self.signal, "index": self.index, "lag": self.lag}


def _t(lag: int) -> str:
    """``t-3`` for lag 3, ``t`` for lag 0 (an input's direct term)."""
    return f"t-{lag}" if lag else "t"


def _lag_runs(lags: Sequence[int]) -> str:
    """``[1, 2, 3, 6, 7]`` -> ``t-1..t-3,t-6,t-7``: runs of three or more consecutive lags collapse with ``..``."""
    vals = sorted({int(v) for v in lags})
    parts: list[str] = []
    i = 0
    while i < len(vals):
        j = i
        while j + 1 < len(vals) and vals[j + 1] == vals[j] + 1:
            j += 1
        if j - i >= 2:
            parts.append(f"{_t(vals[i])}..{_t(vals[j])}")
        else:
            parts.extend(_t(v) for v in vals[i : j + 1])
        i = j + 1
    return ",".join(parts)


def format_lags(output_name: str, y_lags: Sequence[int], input_names: Sequence[str], u_lags: Sequence[Sequence[int]]) -> str:
    """The one way streamid writes a model's regressors: signal names with their lags.

    ``format_lags("force_N", [1, 2], ["velocity_cm_s"], [[1, 2, 3]])`` is
    ``"force_N(t-1,t-2) velocity_cm_s(t-1..t-3)"``: the output first, then each input in
    order; a signal with no selected lag is left out; runs of three or more consecutive
    lags collapse with ``..``; ``"(no regressors)"`` when nothing is selected.
    """
    parts = [f"{output_name}({_lag_runs(y_lags)})"] if len(y_lags) else []
    for name, lu in zip(input_names, u_lags):
        if len(lu):
            parts.append(f"{name}({_lag_runs(lu)})")
    return " ".join(parts) if parts else "(no regressors)"


def check_finite(name: str, a: NDArray[np.float64]) -> None:
    """Raise :class:`DataError` naming the first NaN/inf of ``a`` (its sample and column)."""
    if not np.all(np.isfinite(a)):
        idx = np.argwhere(~np.isfinite(a))[0]
        where = f"sample {int(idx[0])}" + (f", column {int(idx[1])}" if a.ndim > 1 and a.shape[1] > 1 else "")
        raise DataError(
            f"{name} must contain only finite numbers (no NaN or inf); got {float(a[tuple(idx)])!r} at {where}"
        )


def as_data(u: ArrayLike, y: ArrayLike, *, min_samples: int = 1,
            copy: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate and convert identification data.

    Parameters
    ----------
    u : array_like, shape (N,) or (N, n_inputs)
        Inputs (a 1-D array is one input).
    y : array_like, shape (N,) or (N, 1)
        Output.
    min_samples : int
        Minimum number of samples accepted.
    copy : bool
        False: float64 arrays are used as they are (a view, no copy of the record), for a reader that never writes
        them (a long record's validation and correlation tests).

    Returns
    -------
    u : ndarray, shape (N, n_inputs), float64, C-contiguous
    y : ndarray, shape (N,), float64

    Raises
    ------
    DataError
        On wrong shapes, different lengths, NaN/inf, or fewer than ``min_samples`` samples.
    """
    try:
        ua = np.array(u, dtype=np.float64, copy=True) if copy else np.asarray(u, dtype=np.float64)
        ya = np.array(y, dtype=np.float64, copy=True) if copy else np.asarray(y, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"u and y must be arrays of numbers; conversion failed: {exc}") from None
    if ua.ndim == 1:
        ua = ua[:, None]
    if ya.ndim == 2 and ya.shape[1] == 1:
        ya = ya[:, 0]
    if ua.ndim != 2 or ua.shape[1] < 1:
        raise DataError(f"u must have shape (N,) or (N, n_inputs) with n_inputs >= 1; got shape {np.shape(u)}")
    if ya.ndim != 1:
        raise DataError(
            f"y must have shape (N,) (one output; identify several outputs one at a time); got shape {np.shape(y)}"
        )
    if ua.shape[0] != ya.shape[0]:
        raise DataError(f"u and y must have the same number of samples; got {ua.shape[0]} and {ya.shape[0]}")
    if ya.shape[0] < min_samples:
        raise DataError(f"at least {min_samples} samples are needed; got {ya.shape[0]}")
    check_finite("u", ua)
    check_finite("y", ya)
    return np.ascontiguousarray(ua), ya


@dataclass(frozen=True)
class Normalisation:
    """Affine map of every signal to [-1, 1] with the min/max of the estimation data.

    ``x_n = 2 (x - low) / (high - low) - 1``. Part of every model.
    """

    u_low: tuple[float, ...]
    u_high: tuple[float, ...]
    y_low: float
    y_high: float

    @classmethod
    def fit(cls, u: NDArray[np.float64], y: NDArray[np.float64]) -> Normalisation:
        """From estimation data; a constant signal raises :class:`DataError`."""
        lo_u, hi_u = u.min(axis=0), u.max(axis=0)
        for i, (lo, hi) in enumerate(zip(lo_u, hi_u)):
            if not hi > lo:
                raise DataError(
                    f"input {i} is constant over the estimation data (min = max = {lo!r}); each signal needs a "
                    "non-zero range to be normalised to [-1, 1]"
                )
        lo_y, hi_y = float(y.min()), float(y.max())
        if not hi_y > lo_y:
            raise DataError(
                f"the output is constant over the estimation data (min = max = {lo_y!r}); it needs a non-zero "
                "range to be normalised to [-1, 1]"
            )
        if not (np.isfinite(hi_y - lo_y) and np.all(np.isfinite(hi_u - lo_u))):
            raise DataError(
                f"signal ranges must be finite float64 numbers; got inputs {lo_u}..{hi_u}, output {lo_y}..{hi_y}"
            )
        return cls(tuple(float(v) for v in lo_u), tuple(float(v) for v in hi_u), lo_y, hi_y)

    @property
    def n_inputs(self) -> int:
        return len(self.u_low)

    @property
    def y_half_range(self) -> float:
        """``(high - low) / 2`` of the output: one normalised unit in output units."""
        return 0.5 * (self.y_high - self.y_low)

    def u(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        lo = np.asarray(self.u_low)
        hi = np.asarray(self.u_high)
        un: NDArray[np.float64] = 2.0 * (u - lo) / (hi - lo) - 1.0
        return un

    def y(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        return 2.0 * (y - self.y_low) / (self.y_high - self.y_low) - 1.0

    def y_inverse(self, yn: NDArray[np.float64]) -> NDArray[np.float64]:
        return (yn + 1.0) * (0.5 * (self.y_high - self.y_low)) + self.y_low

    def to_dict(self) -> dict[str, Any]:
        return {
            "rule": "x_n = 2 (x - low) / (high - low) - 1",
            "u_low": list(self.u_low),
            "u_high": list(self.u_high),
            "y_low": self.y_low,
            "y_high": self.y_high,
        }

    @classmethod
    def from_dict(cls, d: Any) -> Normalisation:
        try:
            out = cls(
                tuple(float(v) for v in d["u_low"]),
                tuple(float(v) for v in d["u_high"]),
                float(d["y_low"]),
                float(d["y_high"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(
                "normalisation must be an object with u_low, u_high (lists of numbers), y_low, y_high; "
                f"got {d!r} ({exc})"
            ) from None
        spans = [h - lo for lo, h in zip((*out.u_low, out.y_low), (*out.u_high, out.y_high))]
        if any(math.isfinite(s) and 0 < s < MIN_SPAN for s in spans) or not all(math.isfinite(s) for s in spans):
            raise ModelFormatError(f"normalisation spans (high - low) must be finite and >= {MIN_SPAN:g} for every "
                                   f"signal (too small or too large to evaluate in float64); got {spans}"[:600])
        vals = np.array([*out.u_low, *out.u_high, out.y_low, out.y_high])
        if (
            not np.all(np.isfinite(vals))
            or len(out.u_low) != len(out.u_high)
            or len(out.u_low) == 0
            or not out.y_high > out.y_low
            or not all(h > lo for lo, h in zip(out.u_low, out.u_high))
        ):
            raise ModelFormatError(
                f"normalisation needs finite values with high > low for every signal and >= 1 input; got {d!r}"
            )
        return out


def regressors_at(norm: Normalisation, regs: Sequence[Regressor], u: NDArray[np.float64], y: NDArray[np.float64],
                  samples: NDArray[np.intp]) -> NDArray[np.float64]:
    """The normalised lagged terms ``regs`` of the record ``(u, y)`` (``u`` (N, n_inputs)) at the sample indices
    ``samples`` (each at least their lags), one row each: :func:`regressor_columns`' rows ``samples - start`` of
    ``norm.u(u)``, ``norm.y(y)`` (the same values: the normalisation is elementwise), gathered and normalised
    without the others (a long record's memory is the samples')."""
    return np.column_stack([norm.y(y[samples - g.lag]) if g.signal == "y" else norm.u(u[samples - g.lag])[:, g.index]
                            for g in regs])


def regressor_columns(regs: Sequence[Regressor], un: NDArray[np.float64], yn: NDArray[np.float64],
                      start: int) -> NDArray[np.float64]:
    """The normalised lagged terms ``regs`` of rows ``t >= start`` (one column each; ``start`` at least their lags)."""
    n = yn.shape[0]
    r = np.empty((max(0, n - start), len(regs)))
    for j, reg in enumerate(regs):
        src = yn if reg.signal == "y" else un[:, reg.index]
        r[:, j] = src[start - reg.lag : n - reg.lag]
    return r
