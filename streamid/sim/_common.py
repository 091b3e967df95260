"""Helpers shared by the simulators: the returned trace, seeding and argument checks.

Every simulator returns a :class:`Trace` ``(t_ns, u, y)``: integer-nanosecond
sample times starting at 0, the input and the output, all of equal length.
Random draws go through a :class:`numpy.random.Generator` that the caller passes
in (or an integer seed from which one is made); the global numpy RNG is never
touched.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from streamid.errors import ConfigError

__all__ = [
    "Trace",
    "as_generator",
    "as_signal",
    "check_nonneg_int",
    "check_positive_float",
    "check_positive_int",
    "sample_times_ns",
]


class Trace(NamedTuple):
    """A simulated record, unpackable as ``t_ns, u, y = trace``.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (N,)
        Sample times in integer nanoseconds, ``t_ns[k] = k * period_ns``.
    u : ndarray of float64, shape (N,)
        Input applied at (and, for zero-order-hold devices, held from) ``t_ns[k]``.
    y : ndarray of float64, shape (N,)
        Output measured at ``t_ns[k]``.
    """

    t_ns: NDArray[np.int64]
    u: NDArray[np.float64]
    y: NDArray[np.float64]


def as_generator(rng: np.random.Generator | int) -> np.random.Generator:
    """Return ``rng`` if it is a Generator, else a fresh ``default_rng(rng)`` for an integer seed.

    Parameters
    ----------
    rng : numpy.random.Generator or int
        Generator to draw from, or a non-negative integer seed.

    Returns
    -------
    numpy.random.Generator

    Raises
    ------
    ConfigError
        If ``rng`` is neither (``None`` is refused: results must be reproducible).
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and int(rng) >= 0:
        return np.random.default_rng(int(rng))
    raise ConfigError(
        "the random source must be reproducible; accepted: a numpy.random.Generator or a "
        f"non-negative integer seed; got {rng!r}"
    )


def check_positive_int(name: str, value: object) -> int:
    """Return ``value`` as int if it is an integer >= 1, else raise :class:`ConfigError`."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) >= 1:
        return int(value)
    raise ConfigError(f"{name} must be a positive integer (>= 1); got {value!r}")


def check_nonneg_int(name: str, value: object) -> int:
    """Return ``value`` as int if it is an integer >= 0, else raise :class:`ConfigError`."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) >= 0:
        return int(value)
    raise ConfigError(f"{name} must be a non-negative integer (>= 0); got {value!r}")


def check_positive_float(name: str, value: object) -> float:
    """Return ``value`` as float if it is a finite number > 0, else raise :class:`ConfigError`."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(value, bool) or not np.isfinite(v) or v <= 0.0:
        raise ConfigError(f"{name} must be a finite number > 0; got {value!r}")
    return v


def sample_times_ns(n_samples: int, period_ns: int) -> NDArray[np.int64]:
    """Return ``k * period_ns`` for ``k = 0..n_samples-1`` as int64 nanoseconds."""
    return np.arange(n_samples, dtype=np.int64) * np.int64(period_ns)


def as_signal(name: str, x: object) -> NDArray[np.float64]:
    """Return ``x`` as a finite 1-D float64 array, else raise :class:`ConfigError`."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        raise ConfigError(f"{name} must be a non-empty 1-D array of numbers; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.isfinite(a))[0])
        raise ConfigError(f"{name} must be finite; got {a[bad]!r} at index {bad}")
    return a
