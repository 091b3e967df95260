"""Drift detection on the served model's residuals: a Page-Hinkley test on block error levels.

:class:`PageHinkley` is the test as river (``river.drift.PageHinkley``) and
scikit-multiflow implement it (Page 1954): with the running mean ``x̄`` of the
values seen since the last reset, ``S = max(0, alpha * S + x - x̄ - delta)`` and a
drift is signalled when ``S >= threshold`` once ``min_instances`` values were
seen; the detector then resets.  ``tests/test_drift.py`` reproduces river's
documented example value for value.

:class:`ResidualMonitor` feeds it with what a served model does on incoming data:
the one-step-ahead residuals of the champion are pooled into blocks of
``block_samples`` samples, and each block gives one value
``x = log(mean(e^2) / mse_ref)``, clipped to ``[-clip, clip]``, where ``mse_ref``
is the champion's one-step-ahead mean-square error on its held-out data.  A log
ratio makes the test scale-free (any unit, any output size), blocks make it
independent of the sample rate, and the clip stops one outlying block (a loop
of a replayed log, a glitch) from raising an alarm alone: with the defaults
(:class:`DriftSettings`) at least ``ceil(threshold / (clip - delta))`` = 3
blocks of strongly raised error are needed.  When the champion changes the
monitor restarts with the new model's ``mse_ref``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PageHinkley", "ResidualMonitor", "DriftSettings"]


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
    min_blocks: int = 4

    def detector(self) -> PageHinkley:
        """A fresh Page-Hinkley test with these settings (no forgetting)."""
        return PageHinkley(min_instances=self.min_blocks, delta=self.delta, threshold=self.threshold, alpha=1.0)


class ResidualMonitor:
    """Blocks of a champion's one-step-ahead residuals in, drift alarms out (no clock, no I/O).

    Parameters
    ----------
    settings
        Block length and test parameters.
    period_ns
        The stream's sample period (blocks are ``block_s`` of stream time).
    mse_ref
        The champion's one-step-ahead mean-square error on its held-out data.
    """

    def __init__(self, settings: DriftSettings, period_ns: int, mse_ref: float) -> None:
        self.settings = settings
        self.block_samples = max(1, int(round(settings.block_s * 1e9 / max(1, period_ns))))
        self.mse_ref = max(float(mse_ref), 1e-300)
        self._test = settings.detector()
        self._sum = 0.0
        self._n = 0
        self._low_t_ns: int | None = None  # end of the last block after which the cumulated sum was zero
        self.blocks = 0
        self.last_level = 0.0

    def update(self, t_ns: np.ndarray, e: np.ndarray) -> int | None:
        """Add residuals ``e`` at times ``t_ns``; returns the estimated change time (ns) if a drift is signalled."""
        e = np.asarray(e, dtype=np.float64)
        ok = np.isfinite(e)
        if not ok.all():  # a diverging prediction is the largest possible error level
            e = np.where(ok, e, math.sqrt(self.mse_ref) * 1e3)
        alarm: int | None = None
        i = 0
        while i < e.size:
            take = min(e.size - i, self.block_samples - self._n)
            self._sum += float(np.dot(e[i : i + take], e[i : i + take]))
            self._n += take
            i += take
            if self._n == self.block_samples:
                hit = self._block(int(t_ns[i - 1]))
                if hit is not None and alarm is None:
                    alarm = hit
        return alarm

    def _block(self, t_end_ns: int) -> int | None:
        level = math.log(max(self._sum / self._n, 1e-300) / self.mse_ref)
        self._sum, self._n = 0.0, 0
        clip = self.settings.clip
        x = min(clip, max(-clip, level))
        self.last_level = level
        self.blocks += 1
        if self._test.update(x):
            start = self._low_t_ns if self._low_t_ns is not None else t_end_ns
            self._low_t_ns = None
            return start  # the change began after the last block that left the cumulated sum at zero
        if self._test.sum <= 0.0:
            self._low_t_ns = t_end_ns
        return None
