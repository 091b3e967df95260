"""Drift detection on the served model: a two-sided CUSUM on the output's level relative to its free run.

What is watched
---------------
The stream is cut into blocks of ``block_s`` (at least ``min_block_samples``).
On each block the champion runs free from the block's first ``max_lag``
measured outputs, and the block gives one value, its *level*::

    g = log( rms(y - mean y) / rms(yhat - mean yhat) )

the logarithm of the measured output's amplitude over the model's (both
about their block means).  The common drift of a physical device is a change
of gain (an MR damper's coil warms and its yield force falls, a piezo
depolarises, a sensor's sensitivity ages): it moves ``g`` by ``log(1 + change)``
in either direction.  The block's mean-square error does not see it reliably:
on the simulated MR damper, whose online champions free-run at R^2 ~0.87 on
held-out data, a 20 % *decrease* of the force made their errors smaller
(log-MSE -0.3: the misfit shrinks with the amplitude), and referencing the
error's level to the champion's window gave 100-230 false alarms in 10 minutes
of the looped piezo log, whose error level swings with its excitation.  ``g``
is scale-free, independent of the sample rate, and its stationary spread is
about 0.1 per 0.5 s block on the damper (measured: docs/method.md).

The reference
-------------
When a challenger becomes champion its levels are computed at once on the
window it was accepted on (estimation and held-out parts: its own data, so
no warm-up is needed and the first block after it can already count).  A
model's amplitude error depends on how hard the device is driven (a
hysteretic device's gain changes with amplitude, and so does the misfit of its
model), so the reference is a line in the model's own amplitude::

    g_expected = a + b log rms(yhat - mean yhat)

fitted by least squares on the reference blocks (the amplitude clamped to
the range they span), and a block's value is its *residual* ``g - g_expected``.
Both sides of it come from the model and the input, never from the measured
output, so a gain change of the device moves the residual by the full
``log(1 + change)``.  On the simulated MR damper this conditioning cut the
stationary spread of a 0.5 s block from 0.08-0.13 to 0.03-0.05 and made the
shift after a 20 % change 0.13-0.23 in every seed (0.07-0.21 without).

The spread ``s`` of the residuals is 1.4826 x their median absolute deviation,
never below ``min_spread`` (a handful of reference blocks can agree by chance
more closely than the stream will; a window shorter than ``reference_s`` widens
that floor by ``sqrt(reference_s / window)``: 0.5 s windows saw too little of
the excitation, and the piezo-like 2 kHz streams of the load run raised 1-5
alarms in 120 s where the level of a champion referenced on its first 0.5 s
window sat 10 % low for 2 s of every 10 s loop), times ``sqrt((1 + r1) / (1 - r1))`` with
``r1`` their lag-one autocorrelation (in [0, 0.8]): residuals that come in runs
accumulate in a CUSUM like a shift, and this is their long-run spread.  The
spread used is also never below that of the last ``spread_blocks`` judged
blocks about their own median: a reference window that did not see the
variety of the excitation is widened by what the stream shows (a shift moves
the median of those blocks, not their spread about it).  A window with fewer than
``min_reference_blocks`` blocks gets shorter blocks; one that cannot give
them (or no excited block) leaves the champion unwatched.

Blocks whose output barely moves (its rms below ``min_excitation`` of the
reference blocks' median) are not judged: with no excitation a level cannot be
read.  A free run that diverges counts as a maximal rise.

The test
--------
The tabular CUSUM of Page (1954), as in Montgomery, *Introduction to
Statistical Quality Control* (ch. 9): with ``z = clip((g - g_expected) / s, -clip, clip)``::

    C+ = max(0, C+ + z - k)        C- = max(0, C- - z - k)

and a drift is signalled when either reaches ``h``; both restart at zero.  The
change is estimated to have begun after the last block at which the signalling
side was zero (Montgomery's ``N+``/``N-`` counters).  ``tests/test_drift.py``
checks the implementation against the published in-control and shifted average
run lengths.  The clip keeps one outlying block (the loop point of a replayed
log, a glitch) from raising an alarm alone: with the defaults at least
``ceil(h / (clip - k))`` = 3 blocks are needed.  With ``k`` 1 and ``h`` 5.5 the in-control
average run length is about 310,000 blocks a side for independent normal values (Siegmund's
approximation; ~21 h of 0.5 s blocks for the two sides): real residuals are neither independent nor
normal, and this margin is what kept every stationary record of docs/benchmarks.md free of alarms.
A shift of two spreads is signalled after about 6.2 blocks, of three after about 3.2.  ``k`` 0.5
(1,290 blocks at ``h`` 6: an alarm every ~11 minutes) gave one false alarm in 600 s on two of three
stationary simulated dampers.  ``h`` was 6 (840,000 blocks, a shift of two spreads after 6.7) until the
champions were chosen by their free run (``"fr_est"``, :mod:`streamid.online.stream_config`): the sixth
block after a 20 % change of the simulated damper ends 3.1 s after it, and at 6 three of 32 changes were
signalled there; at 5.5 none of the 32 was later than 2.6 s.  On the stationary records (the simulated
damper 5 x 600 s, the looped real MR damper and piezo logs) the largest value either side reached was 4.0.
When the champion changes, a new monitor starts with the new champion's reference, and the replaced
champion's goes on for one window (:class:`~streamid.online.head.OutputHead`): a signal from either is a
drift.  After a signal every monitor of the output is *spent* (:meth:`DriftMonitor.spend`): one change
raises one event.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["BlockLevels", "Cusum", "DriftMonitor", "DriftSettings", "block_levels", "reference_monitor"]


class Cusum:
    """Two-sided tabular CUSUM of standardised values (Page 1954; Montgomery, ch. 9).

    Parameters
    ----------
    k
        Reference value (allowance), in standard deviations: half the shift to detect quickly.
    h
        Decision interval, in standard deviations.
    clip
        Each value is clipped to ``[-clip, clip]`` first (``inf``: no clipping).
    """

    def __init__(self, k: float = 0.5, h: float = 5.0, clip: float = math.inf) -> None:
        for name, v in (("k", k), ("h", h), ("clip", clip)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or math.isnan(v):
                raise ValueError(f"CUSUM {name} must be a number > 0; got {v!r}")
        if not math.isfinite(h):
            raise ValueError(f"CUSUM h must be a finite number > 0; got {h!r}")
        self.k, self.h, self.clip = float(k), float(h), float(clip)
        self.run = 0  # after a signal: how many values the signalling side had been above zero
        self.reset()

    def reset(self) -> None:
        """Back to zero (after a signal, or when the watched process is replaced)."""
        self.upper = self.lower = 0.0
        self.run_upper = self.run_lower = 0  # values since each side last was zero (Montgomery's N+ and N-)

    def update(self, z: float) -> int:
        """Add one standardised value; +1 if the upper side signals (a rise), -1 the lower, 0 none.

        After a signal both sides restart at zero; :attr:`run` then holds how many values
        the signalling side had been above zero (the change began that many values ago).
        """
        z = min(self.clip, max(-self.clip, float(z)))
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)
        self.run_upper = self.run_upper + 1 if self.upper > 0 else 0
        self.run_lower = self.run_lower + 1 if self.lower > 0 else 0
        side = 1 if self.upper >= self.h else -1 if self.lower >= self.h else 0
        if side:
            self.run = self.run_upper if side > 0 else self.run_lower
            self.reset()
        return side


@dataclass(frozen=True)
class DriftSettings:
    """Settings of the drift monitor (see the module docstring; levels are natural logs of amplitude ratios).

    The defaults were chosen across the simulated MR damper and piezo with +-20 % gain changes at known times
    and the stationary simulated damper and looped real logs (docs/method.md, "Champion, challenger and drift").
    """

    block_s: float = 0.5
    #: fewest samples per block (a slow stream's blocks last longer than ``block_s``)
    min_block_samples: int = 25
    #: a champion's window must give at least this many blocks for its reference (else shorter blocks)
    min_reference_blocks: int = 8
    #: smallest spread of one block's level trusted (0.05: about +-5 % of amplitude), for a reference of at least
    #: ``reference_s`` of stream time; a shorter one has it widened by ``sqrt(reference_s / its duration)``
    min_spread: float = 0.05
    reference_s: float = 3.0
    #: blocks whose output rms is below this fraction of the reference blocks' median are not judged
    min_excitation: float = 0.25
    #: the spread used is also never below that of the last this many judged blocks (about their own median)
    spread_blocks: int = 40
    k: float = 1.0
    h: float = 5.5
    clip: float = 3.0

    def block_samples(self, period_ns: int, window_samples: int) -> int:
        """Samples per block for a stream of this period and windows of this many samples (0: cannot watch)."""
        block = max(self.min_block_samples, round(self.block_s * 1e9 / max(1, period_ns)))
        block = min(block, window_samples // self.min_reference_blocks)
        return block if block >= self.min_block_samples else 0


class DriftMonitor:
    """Block levels in, drift alarms out (no clock, no I/O; see the module docstring).

    Parameters
    ----------
    settings
        Test parameters.
    block_samples
        Samples per block (the free runs' length).
    reference : BlockLevels
        The champion's blocks of its own window.
    """

    def __init__(self, settings: DriftSettings, block_samples: int, reference: BlockLevels,
                 reference_duration_s: float | None = None) -> None:
        ok = np.isfinite(reference.level) & (reference.rms > 0) & np.isfinite(reference.model_rms)
        if not np.any(ok):
            raise ValueError("a drift monitor needs at least one finite reference level")
        g, x = reference.level[ok], np.log(reference.model_rms[ok])
        self.settings = settings
        self.block_samples = max(2, int(block_samples))
        self.amplitude_range = (float(x.min()), float(x.max()))
        if x.size >= 3 and x.max() > x.min():
            self.slope, self.centre = (float(v) for v in np.polyfit(x - x.mean(), g, 1))
            self.centre -= self.slope * float(x.mean())
        else:
            self.slope, self.centre = 0.0, float(np.median(g))
        res = g - self.expected(np.exp(x))
        floor = settings.min_spread
        if reference_duration_s is not None and 0 < reference_duration_s < settings.reference_s:
            floor *= math.sqrt(settings.reference_s / reference_duration_s)  # a short window saw little variety
        self.spread = max(floor, 1.4826 * float(np.median(np.abs(res - np.median(res)))))
        self.persistence = 1.0  # sqrt((1 + r1) / (1 - r1)): a long-run spread for residuals that come in runs
        if res.size >= settings.min_reference_blocks:
            c = res - res.mean()
            r1 = float(c[1:] @ c[:-1] / (c @ c)) if c @ c > 0 else 0.0
            r1 = min(max(r1, 0.0), 0.8)
            self.persistence = math.sqrt((1 + r1) / (1 - r1))
        self.spread *= self.persistence
        self.quiet_rms = settings.min_excitation * float(np.median(reference.rms[ok]))
        self._recent: deque[float] = deque(maxlen=settings.spread_blocks)
        self._test = Cusum(settings.k, settings.h, settings.clip)
        self._zero_ns = [0, 0]  # end of the last block after which the upper / lower side was zero
        self.next_index: int | None = None  # first sample of the next block (stream's current epoch)
        self.epoch = -1
        self.blocks = 0
        self.skipped = 0
        self.spent = False  # a change was signalled against this reference: no further signal
        self.last_level = 0.0  # the last judged block's level relative to the reference (log of a ratio)

    def inherit(self, previous: DriftMonitor) -> None:
        """Start the recent blocks with ``previous``'s (the replaced champion's, on the same output).

        The spread used is never below that of the recent blocks about their median; a new champion
        has none of its own yet, and its reference window can be quieter than the stream (the F-16's
        multisine repeats every 20.48 s, and a 10 s window can hold its calmer half: reference spread
        0.055 where the previous champions' blocks spread 0.15-0.21; a false alarm 2.5 s later).  How
        much a block's level varies is mostly the data's doing, so the previous champion's recent
        residuals stand in until this one's own replace them.
        """
        self._recent.extend(previous._recent)

    def retire(self, watches: int) -> None:
        """The champion was replaced; this monitor goes on next to the new one's and ``watches - 1`` others.

        Its threshold rises by ``log(watches) / (2 k)``: by Siegmund's approximation the in-control
        run length of a CUSUM grows as ``exp(2 k h)``, so each replaced champion's watch raises
        alarms ``watches`` times less often than the champion's, and the output's together at most
        twice as often as one watch.  (With the defaults: h 5.5 -> 6.05, one block more at most.)
        """
        self._test.h = self.settings.h + math.log(max(1, watches)) / (2 * self.settings.k)

    def spend(self) -> None:
        """After a change is signalled (by this or another monitor of the output): raise no further signal.

        The reference predates the change, so every later block would only signal it again; a new
        champion brings a new monitor.  Levels are still computed and shown.
        """
        self.spent = True
        self._test.reset()

    def summary(self) -> dict[str, Any]:
        """What the status shows of this watch (levels are natural logs of amplitude ratios)."""
        last = self.last_level if math.isfinite(self.last_level) else None
        return {"block_samples": self.block_samples, "blocks": self.blocks, "skipped": self.skipped,
                "last_level": last, "spread": self.current_spread(), "cusum_up": self._test.upper,
                "cusum_down": self._test.lower, "h": self._test.h, "spent": self.spent}

    def current_spread(self) -> float:
        """The reference's spread, or the recent blocks' own (about their median) if it is wider."""
        if len(self._recent) < self.settings.min_reference_blocks:
            return self.spread
        r = np.fromiter(self._recent, dtype=np.float64)
        return max(self.spread, self.persistence * 1.4826 * float(np.median(np.abs(r - np.median(r)))))

    def expected(self, model_rms: Any) -> Any:
        """The reference's level for blocks of this model amplitude (clamped to the reference's range)."""
        lo, hi = self.amplitude_range
        return self.centre + self.slope * np.clip(np.log(model_rms), lo, hi)

    def block(self, level: float, rms: float, model_rms: float, t_end_ns: int) -> int | None:
        """Add one block (its level, output rms and model rms); returns the estimated start (ns) of a change
        if a drift is signalled."""
        self.blocks += 1
        if math.isnan(level) or (math.isfinite(level) and not rms >= self.quiet_rms):
            self.skipped += 1  # no excitation: a level cannot be read
            return None
        if math.isfinite(level):
            self.last_level = level - float(self.expected(model_rms))
            self._recent.append(self.last_level)
            z = self.last_level / self.current_spread()
        else:  # the free run diverged or collapsed on this block
            self.last_level, z = math.inf, self.settings.clip
        if self.spent:
            return None
        if self.blocks - self.skipped == 1:
            self._zero_ns = [t_end_ns, t_end_ns]  # (the first block's end: the best known before it)
        side = self._test.update(z)
        if side:
            start = self._zero_ns[0 if side > 0 else 1]
            self._zero_ns = [t_end_ns, t_end_ns]
            return start  # the change began after the last block at which the signalling side was zero
        if self._test.upper == 0.0:
            self._zero_ns[0] = t_end_ns
        if self._test.lower == 0.0:
            self._zero_ns[1] = t_end_ns
        return None


@dataclass(frozen=True)
class BlockLevels:
    """Per block: ``level = log(rms / model_rms)``, the output's ``rms`` and the free run's ``model_rms``."""

    level: NDArray[np.float64]
    rms: NDArray[np.float64]
    model_rms: NDArray[np.float64]


def block_levels(model: Any, u: NDArray[np.float64], y: NDArray[np.float64], block: int) -> BlockLevels:
    """Levels ``log(rms(y_c) / rms(yhat_c))`` of ``model``'s free runs over consecutive blocks (:class:`BlockLevels`).

    Each block's run starts from the ``max_lag`` measured outputs before it (the first block from
    the data's first ``max_lag`` samples); ``_c``: about the block's mean.  A run that diverges, or
    stays constant, gives a level of ``inf``; an output that stays constant gives ``nan``.
    """
    L = model.max_lag
    starts = list(range(L, y.shape[0] - block + 1, block))
    if not starts:
        return BlockLevels(np.empty(0), np.empty(0), np.empty(0))
    runs = [(u[a - L : a + block], y[a - L : a]) for a in starts]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        sims = np.stack([s[L:] for s in model.simulate_many(runs)])
        ys = np.stack([y[a : a + block] for a in starts])
        ry = np.sqrt(np.mean((ys - ys.mean(axis=1, keepdims=True)) ** 2, axis=1))
        rs = np.sqrt(np.mean((sims - sims.mean(axis=1, keepdims=True)) ** 2, axis=1))
        level = np.log(ry / rs)
    level = np.where(np.isfinite(rs) & (rs > 0), level, np.inf)
    level = np.where(ry > 0, level, np.nan)
    return BlockLevels(level, ry, rs)


def reference_monitor(settings: DriftSettings, model: Any, u: NDArray[np.float64], y: NDArray[np.float64],
                      period_ns: int) -> DriftMonitor | None:
    """A monitor of a new champion, referenced on the window ``u``/``y`` it was accepted on (None: unwatchable)."""
    block = settings.block_samples(period_ns, y.shape[0] - model.max_lag)
    if not block:
        return None
    ref = block_levels(model, u, y, block)
    if not np.any(np.isfinite(ref.level) & (ref.rms > 0)):
        return None
    return DriftMonitor(settings, block, ref, y.shape[0] * period_ns / 1e9)
