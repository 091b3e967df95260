"""The kept model's prediction interval, calibrated on data held out from fitting (split conformal).

The estimation record is split in two halves. The kept model's structure (lags, centres, widths; each member's,
for an ensemble) is refitted by least squares on the first half alone, then free-run over the whole record from
its first measured outputs (beyond one chunk: over the second half, from that half's own first measured outputs);
the second half, which that fit never saw, gives the calibration scores
``|y(t) - centre(t)| / (scale + spread(t) + beyond * far(t))`` (:mod:`streamid.model.uncertainty`), ``scale`` the RMS of its free-run
error there. Their conformal quantiles at :data:`~streamid.model.uncertainty.LEVELS` and ``scale`` are what the
model carries. What this covers and what it does not: docs/method.md ("The prediction interval").
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.choice.selection import refit_weights
from streamid.engine.search.rows import spaced_rows
from streamid.errors import DataError
from streamid.model.freerun import chunked_runs
from streamid.model.limits import CHUNK_ROWS
from streamid.model.narx import Model
from streamid.model.uncertainty import BEYOND, LEVELS, MIN_CALIBRATION, Interval, conformal_quantiles, member_spread

__all__ = ["METHOD", "METHOD_IN_SAMPLE", "UNSTABLE_HALF_R2", "calibrate", "with_interval"]

METHOD = ("split-conformal: the model's structure refitted on the estimation record's first half, its free run "
          "scored on the second half")
METHOD_IN_SAMPLE = ("conformal on the model's own free-run errors over the estimation record's second half (in sample: "
                    "the model refitted on the first half left the record)")
#: A half-model whose held-out free-run R^2 is below this, where the model's own is not, is taken as unstable.
UNSTABLE_HALF_R2 = 0.0


def calibrate(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], ridge: float,
              threads: int = 1) -> tuple[Interval | None, dict[str, Any]]:
    """The interval of ``model`` from its estimation record ``(u, y)`` and the evidence (``metrics.calibration``):
    ``samples``, ``scale``, the refitted half's held-out free-run R^2 (``r2_fr_held_out``; the model's own over the
    second half, ``r2_fr_second_half``, only when that one is below :data:`UNSTABLE_HALF_R2`), or ``reason`` when
    no interval could be made (a record too short, a refit that failed, a held-out free run that diverged).
    A first half beyond one chunk (:data:`~streamid.model.limits.CHUNK_ROWS` rows) is refitted on that many evenly
    spaced rows of it (``fit_rows`` in the evidence), as every least squares of a long record that needs no
    contiguity. ``threads``: an ensemble's members free-run in that many threads (the same interval to the bit)."""
    n = int(y.shape[0])
    h = n // 2
    if n - h < MIN_CALIBRATION or h < model.max_lag + 2:
        return None, {"reason": f"too few samples to hold out ({n}; at least {2 * MIN_CALIBRATION} are needed)"}
    spaced = spaced_rows(h - model.max_lag)  # None: up to one chunk, every row (as always)
    samples = None if spaced is None else model.max_lag + spaced
    try:
        half = refit_weights(model, u[:h], y[:h], ridge, samples, threads, fitness=False)  # its weights only
    except DataError as exc:
        return None, {"reason": f"the model could not be refitted on the first half ({exc})"}
    err, spread = _held_out(half, u, y, h, threads)  # the free run's error and the band's own terms there
    if not (np.all(np.isfinite(err)) and np.all(np.isfinite(spread))):
        return None, {"reason": "the model refitted on the first half diverged in free run over the second half",
                      "samples": n - h}
    var = float(np.var(y[h:]))
    r2 = 1.0 - float(np.mean(err**2)) / var if var > 0 else None
    method, held_out, own_r2 = METHOD, True, None
    if r2 is not None and r2 < UNSTABLE_HALF_R2:  # only then is the model's own free run needed (one more run)
        own_err, own_spread = _held_out(model, u, y, h, threads)
        own_r2 = 1.0 - float(np.mean(own_err**2)) / var if np.all(np.isfinite(own_err)) else None
        if own_r2 is not None and own_r2 >= UNSTABLE_HALF_R2:
            # the half's refit leaves the record (a structure too large for half the rows, e.g. a long linear part
            # of hundreds of lags) where the model itself does not: its errors say nothing of the model's; the
            # model's own errors on the second half are used instead (in sample: narrower than a held-out band)
            err, method, held_out, spread = own_err, METHOD_IN_SAMPLE, False, own_spread
    scale = float(np.sqrt(np.mean(err**2)))
    den = scale + spread
    scores = np.divide(np.abs(err), den, out=np.zeros_like(err), where=den > 0)
    quantiles = conformal_quantiles(scores, LEVELS)
    evidence = {"method": method, "held_out": held_out, "samples": n - h, "scale": scale, "r2_fr_held_out": r2,
                "r2_fr_second_half": own_r2, "mean_spread": float(np.mean(spread)),  # the members' spread and the growth past the domain, mean
                "quantile_90": quantiles[LEVELS.index(0.9)],
                **({} if samples is None else {"fit_rows": int(samples.size)})}
    return Interval(LEVELS, quantiles, scale, n - h, method, BEYOND), evidence


def _held_out(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], h: int,
              threads: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Over samples ``h ..`` of the record: the model's free-run error and the band's own terms (the members'
    spread and the growth past the domain), its free run made a chunk at a time (only that part kept: a long
    record's memory is its held-out half's, not its members' paths).

    Up to one chunk (:data:`~streamid.model.limits.CHUNK_ROWS` rows) the free run starts at the record's first
    measured outputs, as always; beyond it, at the second half's own (samples ``h - max_lag .. h``), as a validation
    on another record starts at that record's: the first half's free run, never scored, is not made (half the work).
    A stable model forgets its initial state within its memory, so only the first few tens of the half's samples
    differ; measured on the 1,000,000-sample reactor records (docs/method.md, "Records longer than one chunk")."""
    L, n = model.max_lag, int(y.shape[0])
    ua = u.reshape(n, -1)
    o = h - L if n > CHUNK_ROWS and h - L > 0 else 0  # where the free run starts
    err, terms = np.empty(n - h), np.empty(n - h)
    for a, paths, centre, far in chunked_runs(model, ua[o:], y[o : o + L], CHUNK_ROWS, threads, far_from=h - o):
        a, b = o + a, o + a + paths.shape[1]
        if b > h and far is not None:
            s = max(a, h)
            with np.errstate(over="ignore", invalid="ignore"):
                err[s - h : b - h] = y[s:b] - centre[s - a :]
                terms[s - h : b - h] = member_spread(paths[:, s - a :]) + BEYOND * far[s - a :]
    return err, terms


def with_interval(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], ridge: float,
                  threads: int = 1) -> Model:
    """``model`` carrying its calibrated interval (or none), the evidence in ``metrics.calibration``."""
    interval, evidence = calibrate(model, u, y, ridge, threads)
    return replace(model, interval=interval, metrics={**model.metrics, "calibration": evidence})
