"""Drift detection on the served model: a Page-Hinkley test on the level of its short free-run errors.

:class:`PageHinkley` is the test as river (``river.drift.PageHinkley``) and
scikit-multiflow implement it (Page 1954): with the running mean ``x̄`` of the
values seen since the last reset, ``S = max(0, alpha * S + x - x̄ - delta)`` and a
drift is signalled when ``S >= threshold`` once ``min_instances`` values were
seen; the detector then resets.  ``tests/test_drift.py`` reproduces river's
documented example value for value.

:class:`DriftMonitor` feeds it with what the served model (the champion) does on
incoming data.  The stream is cut into blocks of ``block_s`` (at least
``min_block_samples``, at most the held-out part of a window); on each block the champion runs free from the
block's first ``max_lag`` measured outputs, and the block gives one value
``x = log(MSE_block)``, clipped to within ``clip`` of the running mean of the
values seen so far (the test's ``x̄``: the champion's own typical level on
current data, learnt in its first blocks; its error on the few held-out
seconds it was accepted on proved a poor reference, the piezo's level swinging
by e^2 across stationary blocks).  Short free runs, not one-step-ahead residuals: at high sample rates the
one-step-ahead prediction leans on the measured last output and hardly sees a
20 % change of a device's gain (measured on the simulated MR damper: OSA R^2
0.982 -> 0.987 across such a change, block free-run error x2.6), while a model
is served for its free run.  A logarithm makes the test scale-free, blocks make
it independent of the sample rate, and the clip stops one outlying block (the
loop point of a replayed log, a glitch) from raising an alarm alone: with the
defaults (:class:`DriftSettings`) at least ``ceil(threshold / (clip - delta))``
= 3 blocks of strongly raised error are needed.  When the champion changes the
monitor restarts with the new model's reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PageHinkley", "DriftMonitor", "DriftSettings", "block_errors"]


class PageHinkley:
    """Page-Hinkley test for an increase of the mean of a sequence (river's semantics).

    Parameters
    ----------
    min_instances
        Values seen (since the last reset) before a drift can be signalled.
    delta
        Tolerated increase of the mean (the values' units).
    threshold
        Cumulated increase beyond ``delta`` that signals a drift (lambda).
    alpha
        Forgetting factor of the cumulated sum (1: none).
    """

    def __init__(self, min_instances: int = 30, delta: float = 0.005, threshold: float = 50.0,
                 alpha: float = 1 - 0.0001) -> None:
        if min_instances < 1:
            raise ValueError(f"min_instances must be an integer >= 1; got {min_instances!r}")
        if not threshold > 0:
            raise ValueError(f"threshold must be a number > 0; got {threshold!r}")
        if not 0 < alpha <= 1:
            raise ValueError(f"alpha must be a number in (0, 1]; got {alpha!r}")
        self.min_instances, self.delta, self.threshold, self.alpha = min_instances, delta, threshold, alpha
        self.drift_detected = False
        self._reset()

    def _reset(self) -> None:
        self.sample_count = 1
        self.x_mean = 0.0
        self.sum = 0.0
        self.drift_detected = False

    def reset(self) -> None:
        """Forget everything seen (e.g. the monitored model changed)."""
        self._reset()

    def update(self, x: float) -> bool:
        """Add one value; returns whether it signals a drift (the next update starts afresh)."""
        if self.drift_detected:
            self._reset()
        self.x_mean += (x - self.x_mean) / float(self.sample_count)
        self.sum = max(0.0, self.alpha * self.sum + (x - self.x_mean - self.delta))
        self.sample_count += 1
        self.drift_detected = self.sample_count >= self.min_instances and self.sum >= self.threshold
        return self.drift_detected


@dataclass(frozen=True)
class DriftSettings:
    """Settings of the residual drift monitor (see the module docstring; units: log of an MSE ratio).

    The defaults were chosen on the simulated MR damper and piezo with a 20 % parameter change and on the stationary
    simulators and looped real logs (docs/method.md, "Champion, challenger and drift").
    """

    block_s: float = 0.25
    delta: float = 0.5
    threshold: float = 3.0
    clip: float = 1.5
    min_blocks: int = 8
    #: fewest samples per block (a slow stream's blocks last longer than ``block_s``; the error of a free run of a
    #: handful of samples is too noisy a level: 2-sample blocks of the CSTR, one sample every 6 s, gave 79 alarms)
    min_block_samples: int = 25

    def monitor(self, period_ns: int, max_block: int) -> DriftMonitor | None:
        """A monitor of a new champion: blocks of ``block_s``, at least ``min_block_samples``, at most ``max_block``
        (its held-out samples after the lags); None if the held-out part is shorter than the minimum block."""
        block = min(max(self.min_block_samples, round(self.block_s * 1e9 / max(1, period_ns))), max_block)
        return DriftMonitor(self, block) if block >= self.min_block_samples else None

    def detector(self) -> PageHinkley:
        """A fresh Page-Hinkley test with these settings (no forgetting)."""
        return PageHinkley(min_instances=self.min_blocks, delta=self.delta, threshold=self.threshold, alpha=1.0)


class DriftMonitor:
    """Block free-run errors in, drift alarms out (no clock, no I/O; see the module docstring).

    Parameters
    ----------
    settings
        Test parameters.
    block_samples
        Samples per block (the free runs' length).
    """

    def __init__(self, settings: DriftSettings, block_samples: int) -> None:
        self.settings = settings
        self.block_samples = max(2, int(block_samples))
        self._test = settings.detector()
        self._low_t_ns: int | None = None  # end of the last block after which the cumulated sum was zero
        self.next_index: int | None = None  # first sample of the next block (stream's current epoch)
        self.epoch = -1
        self.blocks = 0
        self.last_level = 0.0

    def block(self, mse: float, t_end_ns: int) -> int | None:
        """Add one block's free-run MSE; returns the estimated start (ns) of a change if a drift is signalled."""
        t, clip = self._test, self.settings.clip
        mean = t.x_mean if t.sample_count > 1 and not t.drift_detected else None
        level = math.log(max(mse, 1e-300)) if math.isfinite(mse) else (mean or 0.0) + clip
        self.last_level = level - (mean if mean is not None else level)  # relative to the champion's typical level
        self.blocks += 1
        x = level if mean is None else min(mean + clip, max(mean - clip, level))
        if t.update(x):
            start = self._low_t_ns if self._low_t_ns is not None else t_end_ns
            self._low_t_ns = None
            return start  # the change began after the last block that left the cumulated sum at zero
        if self._test.sum <= 0.0:
            self._low_t_ns = t_end_ns
        return None


def block_errors(model: Any, u: np.ndarray, y: np.ndarray, block: int) -> np.ndarray:
    """Mean-square errors of ``model``'s free runs over consecutive blocks of ``block`` samples of ``u``/``y``.

    Each block's run starts from the ``max_lag`` measured outputs before it (the first block from
    the data's first ``max_lag`` samples); a diverging run gives ``inf``.
    """
    L = model.max_lag
    starts = list(range(L, y.shape[0] - block + 1, block))
    if not starts:
        return np.empty(0)
    runs = [(u[a - L : a + block], y[a - L : a]) for a in starts]
    with np.errstate(over="ignore", invalid="ignore"):
        sims = model.simulate_many(runs)
        out = np.array([np.mean((y[a : a + block] - sim[L:]) ** 2) for a, sim in zip(starts, sims, strict=True)])
    return np.where(np.isfinite(out), out, np.inf)


