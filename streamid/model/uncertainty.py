"""A model's free-run prediction interval: what it needs to say how far the device may be from its simulation.

The band at sample ``t`` of a free run is ``centre(t) +- q_level * (scale + spread(t) + beyond * far(t))``:

* ``centre`` the model's free run (an ensemble's combined members);
* ``spread(t)`` the standard deviation of the members' own free runs at ``t`` (0 for a single network): where the
  restarts disagree about the device, the band widens;
* ``scale`` the free-run error's root mean square on the calibration record (output units): the residual noise
  and the error the members share;
* ``far(t)`` how far the model's farthest regressor at ``t`` lies beyond its estimation range
  (:func:`streamid.model.domain.excess`, in units of the range's half-span) times the output's half-range: beyond
  its data a network of Gaussian bumps does not know the device, and the band says so by growing as fast as the
  regressors leave (``beyond`` 1; 0 in documents written before the rule, whose bands it leaves as they were);
* ``q_level`` the split-conformal quantile of the calibration scores
  ``|y(t) - centre(t)| / (scale + spread(t) + beyond * far(t))`` at the level: the ``ceil((n + 1) level) / n``
  empirical quantile of the ``n`` scores.

The calibration record is data held out from fitting (the engine's :mod:`~streamid.engine.choice.calibration`
says which; docs/method.md says what the band covers and what it does not). The document keeps the quantiles of a
few levels (:data:`LEVELS`), so that a reader needs no calibration data to draw any of them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.errors import DataError, ModelFormatError
from streamid.model.domain import far_from_domain

__all__ = ["BEYOND", "Band", "DEFAULT_LEVEL", "Interval", "LEVELS", "LOW_COVERAGE", "WIDTH_PARTS", "band_coverage", "coverage_figures",
           "conformal_quantiles", "interval_report", "interval_text", "member_spread"]

#: The levels whose quantiles a model carries; the default one is drawn and reported.
LEVELS: tuple[float, ...] = (0.5, 0.8, 0.9, 0.95, 0.99)
#: The level reported by ``identify``, ``validate``, the daemon and ``watch``.
DEFAULT_LEVEL = 0.9
#: Fewest calibration samples a quantile is made from (fewer: no interval).
MIN_CALIBRATION = 20
#: How fast the band grows beyond the estimation domain (``beyond`` of the intervals calibrated now): by the
#: output's half-range per half-span a regressor leaves its range (docs/method.md, "The prediction interval").
BEYOND = 1.0
_FORM = ("an object with levels (a list of numbers in (0, 1)), quantiles (one number >= 0 each), scale (a number >= 0), "
         "samples (an integer), method (text) and optionally beyond (a number >= 0)")

#: The band's half-width terms, in the order :func:`coverage_figures` takes them, and how a report names them.
WIDTH_PARTS: tuple[str, ...] = ("scale", "spread", "beyond")
_PART_TEXT = {"scale": "the error's scale", "spread": "the networks' disagreement",
              "beyond": "the distance beyond the estimation domain"}


class Band(NamedTuple):
    """A free run with its interval: the simulated output and the band's lower and upper paths (output units)."""

    y: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]


def member_spread(paths: NDArray[np.float64]) -> NDArray[np.float64]:
    """The standard deviation of the members' paths ``(K, N)`` at each sample (zeros for one member)."""
    if paths.shape[0] < 2:
        return np.zeros(paths.shape[1])
    with np.errstate(over="ignore", invalid="ignore"):
        s: NDArray[np.float64] = np.std(paths, axis=0)
    return s


def conformal_quantiles(scores: NDArray[np.float64], levels: Sequence[float] = LEVELS) -> tuple[float, ...]:
    """The split-conformal quantile of ``scores`` at each level: the ``ceil((n + 1) level)``-th smallest score
    (the largest score when that exceeds ``n``: the finite-sample guarantee needs ``n >= 1 / (1 - level) - 1``)."""
    s = np.sort(np.asarray(scores, dtype=np.float64))
    n = s.shape[0]
    if n < MIN_CALIBRATION:
        raise DataError(f"a prediction interval needs at least {MIN_CALIBRATION} calibration samples; got {n}")
    return tuple(float(s[min(n, math.ceil((n + 1) * lv)) - 1]) for lv in levels)


@dataclass(frozen=True)
class Interval:
    """What a model carries for its free-run interval (see the module docstring)."""

    levels: tuple[float, ...]
    quantiles: tuple[float, ...]
    scale: float
    samples: int
    method: str = "split-conformal"
    beyond: float = 0.0  # the band's growth beyond the estimation domain (BEYOND; 0: documents without the rule)

    def __post_init__(self) -> None:
        ok = (len(self.levels) == len(self.quantiles) >= 1
              and isinstance(self.beyond, float) and math.isfinite(self.beyond) and self.beyond >= 0.0
              and all(isinstance(v, float) and 0.0 < v < 1.0 for v in self.levels)
              and all(isinstance(q, float) and math.isfinite(q) and q >= 0.0 for q in self.quantiles)
              and isinstance(self.scale, float) and math.isfinite(self.scale) and self.scale >= 0.0
              and isinstance(self.samples, int) and self.samples >= 0)
        if not ok:
            raise ModelFormatError(f"model field 'interval' must be {_FORM}; got levels {self.levels!r}, quantiles "
                                   f"{self.quantiles!r}, scale {self.scale!r}, samples {self.samples!r}, beyond "
                                   f"{self.beyond!r}")

    def quantile(self, level: float) -> float:
        """The quantile of ``level`` (one of :attr:`levels`)."""
        for lv, q in zip(self.levels, self.quantiles):
            if abs(lv - level) < 1e-12:
                return q
        raise DataError(f"interval level must be one of {', '.join(f'{v:g}' for v in self.levels)} (the levels this "
                        f"model was calibrated at); got {level!r}")

    def band(self, centre: NDArray[np.float64], paths: NDArray[np.float64], level: float, measured: int,
             far: NDArray[np.float64] | None = None) -> Band:
        """The band of ``level`` around ``centre`` (the members' ``paths`` ``(K, N)`` give the spread; ``far`` how
        far beyond the estimation domain each sample lies, in output units: see the module docstring); the first
        ``measured`` samples are measured outputs, their band of width zero."""
        with np.errstate(over="ignore", invalid="ignore"):
            half = self.quantile(level) * (self.widths(paths, far))
        half[:measured] = 0.0
        return Band(centre, centre - half, centre + half)

    def widths(self, paths: NDArray[np.float64], far: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """``scale + spread(t) + beyond * far(t)``: the band's half-width over its quantile (and the calibration
        scores' denominator)."""
        spread, past = self.terms(paths, far)
        w = self.scale + spread
        if past is not None:
            w = w + past
        return w

    def terms(self, paths: NDArray[np.float64],
              far: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """The half-width's two terms that vary along a run (over its quantile): the members' ``spread(t)`` and
        ``beyond * far(t)`` (None without the rule or without ``far``)."""
        past = self.beyond * far if far is not None and self.beyond > 0.0 else None
        return member_spread(paths), past

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"method": self.method, "levels": list(self.levels), "quantiles": list(self.quantiles),
                             "scale": self.scale, "samples": self.samples}
        if self.beyond > 0.0:
            d["beyond"] = self.beyond
            d["band"] = ("centre(t) +- quantiles[level] * (scale + std of the members' free runs at t + beyond * "
                         "max(0, max_j |x_j(t)| - 1) * (y_high - y_low) / 2), x_j the normalised regressors at t "
                         "(the output's from the free run itself)")
        else:
            d["band"] = "centre(t) +- quantiles[level] * (scale + std of the members' free runs at t)"
        return d

    @classmethod
    def from_dict(cls, d: Any) -> Interval:
        if not isinstance(d, Mapping):
            raise ModelFormatError(f"model field 'interval' must be {_FORM}; got {type(d).__name__}")
        try:
            levels = tuple(float(v) for v in d["levels"])
            quantiles = tuple(float(v) for v in d["quantiles"])
            samples = d["samples"]
            if isinstance(samples, bool) or not isinstance(samples, int):
                raise TypeError(f"samples {samples!r}")
            return cls(levels, quantiles, float(d["scale"]), samples, str(d.get("method", "split-conformal"))[:200],
                       float(d.get("beyond", 0.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(f"model field 'interval' must be {_FORM} ({type(exc).__name__}: {exc})") from None


def band_coverage(y: ArrayLike, band: Band, start: int = 0) -> dict[str, float]:
    """How a band did on a measured record ``y`` from sample ``start``: the share of samples inside it
    (``coverage``) and its mean width (output units; ``width_over_std``: over ``y``'s standard deviation there)."""
    ya = np.asarray(y, dtype=np.float64)[start:]
    lo, hi = band.lower[start:], band.upper[start:]
    if ya.shape[0] == 0:
        raise DataError("coverage needs at least one measured sample after the initial outputs")
    with np.errstate(invalid="ignore", over="ignore"):
        inside = (ya >= lo) & (ya <= hi)
        width = float(np.mean(hi - lo))
    return coverage_figures(float(np.mean(inside)), width, float(np.std(ya)))


def coverage_figures(coverage: float, width: float, std: float,
                     parts: tuple[float, float, float] | None = None) -> dict[str, Any]:
    """:func:`band_coverage`'s figures from the share inside, the mean width and the measured output's standard
    deviation (a record judged a piece at a time sums them itself: ``streamid.engine.validation``). ``parts``: the
    means over the scored samples of the half-width's three terms (``scale``, the members' ``spread``, the growth
    ``beyond`` the domain: :meth:`Interval.widths`); given, ``width_from`` says what share of the width each is
    (omitted where they are not finite: a run that diverged)."""
    out: dict[str, Any] = {"coverage": coverage, "width": width if math.isfinite(width) else math.inf,
                           "width_over_std": (width / std) if std > 0 and math.isfinite(width) else math.inf}
    if parts is not None:
        total = math.fsum(parts)
        if math.isfinite(total) and total > 0.0:
            out["width_from"] = {k: v / total for k, v in zip(WIDTH_PARTS, parts)}
    return out


def interval_report(model: Any, u: NDArray[np.float64], y: NDArray[np.float64], level: float = DEFAULT_LEVEL,
                    free_run: NDArray[np.float64] | None = None) -> dict[str, Any] | None:
    """The model's interval of ``level`` on a measured record (free run from its first ``max_lag`` outputs):
    ``level``, ``coverage``, mean ``width`` and ``width_over_std`` over the scored samples; None when the model
    carries no interval. ``model`` a Model (read, not imported); ``free_run``: its free run on the record when the
    caller has it (a single network's band is then made from it, not simulated again)."""
    interval = getattr(model, "interval", None)
    if interval is None:
        return None
    L = int(model.max_lag)
    with np.errstate(over="ignore", invalid="ignore"):
        if free_run is not None and len(getattr(model, "members", (model,))) == 1:
            band = interval.band(free_run, free_run[None, :], float(level), L, far_from_domain(model, u, free_run))
        else:
            band = model.simulate(u, y[:L], interval=level)
    return {"level": float(level), **band_coverage(y, band, L)}


#: Coverage of the default interval under which a record is called one the model does not know (the suite's
#: "silent failure" needs both a poor free run and coverage under it: docs/method.md).
LOW_COVERAGE = 0.8


def interval_text(report: Mapping[str, Any] | None, record: str, unit: str = "") -> str:
    """One line on a model's interval over a record (``report`` from :func:`interval_report`; None: it has none)."""
    if report is None:
        return "interval: none (the model carries no prediction interval)"
    cov, width, rel = float(report["coverage"]), float(report["width"]), float(report["width_over_std"])
    line = (f"interval: the {100 * report['level']:g} % free-run band covers {100 * cov:.1f} % of the {record} samples, "
            f"mean width {width:.4g}{(' ' + unit) if unit else ''} ({rel:.2f} of the output's standard deviation)")
    parts = report.get("width_from")
    if parts:
        said = [f"{100 * float(parts[k]):.0f} % from {_PART_TEXT[k]}" for k in WIDTH_PARTS
                if 100 * float(parts.get(k, 0.0)) >= 0.5]
        if said:
            line += "; its width: " + ", ".join(said)
    if cov < LOW_COVERAGE:
        line += (f"; under {100 * LOW_COVERAGE:g} %: the model does not know this record (a finding, not an error: "
                 "trust its free run here less than its R2 says)")
    return line
