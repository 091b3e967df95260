"""Every compiled loop of the model and the engine, compiled (or loaded from numba's cache) before time-bound work."""

from __future__ import annotations

import numpy as np

from streamid.engine.choice.sensitivities import free_run_sensitivities
from streamid.engine.fit.kernels import exp2_rows, gram_rows
from streamid.model.kernels import recursion, scaled_distances

__all__ = ["warm_up_kernels"]


def warm_up_kernels() -> None:
    """Compile the kernels now (the first time on a machine, about 1 s) or load them from the cache, so that
    no time-bound caller (the daemon's first decision) pays for it. Idempotent and cheap once done.

    The callers pass writable C-ordered float64 arrays, int64 lags and an int ``L``, as here: numba
    compiles one version per argument types, so these are the versions they use."""
    one = np.ones(1, dtype=np.int64)
    recursion(np.zeros((1, 3, 1)), one, one - 1, np.zeros((1, 1, 1)), np.zeros((1, 1, 1)), np.ones((1, 1)), one,
              np.zeros((1, 1)), one, np.zeros((1, 1)), np.zeros((3, 1)), np.zeros((3, 1)), 1)
    free_run_sensitivities(np.zeros((3, 1)), np.zeros((1, 1)), np.ones(1), np.ones(1, dtype=np.int64), np.zeros(1),
                           np.zeros(1), np.zeros(3), np.zeros(3), 1, np.zeros((3, 0)), 0, np.zeros((1, 1)))
    scaled_distances(np.zeros((1, 1)), np.zeros((1, 1)), -np.ones(1), np.empty((1, 1)))
    exp2_rows(np.zeros((1, 2, 3)), 1, 2)
    gram_rows(np.zeros((1, 3, 4)), 1, 3, np.empty((1, 3, 2)))
