"""A model's estimation domain: whether a record's values lie beyond the range the estimation data spanned
(a network of Gaussian bumps does not extrapolate)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["BEYOND_RANGE", "beyond_range"]


#: A validation signal counts as beyond the estimation range when it leaves it by more than this fraction of the
#: estimation span (the free-run range guard of the final choice allows 0.25 of it; docs/method.md).
BEYOND_RANGE = 0.25


def beyond_range(lo: float, hi: float, values: NDArray[np.float64]) -> bool:
    """Whether ``values`` leave ``[lo, hi]`` by more than :data:`BEYOND_RANGE` of its span (never for a zero span)."""
    span = hi - lo
    return bool(span > 0 and len(values) and max(float(np.max(values)) - hi, lo - float(np.min(values))) >
                BEYOND_RANGE * span)
