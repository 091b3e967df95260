"""Adaptive Binary Harmony Search with individual selection (paper section 3.2, eqs. 10-13).

Pure functions; every random draw comes from the Generator passed in.

Choices left open by the paper, as streamid makes them
------------------------------------------------------
* Schedule (eq. 10): ``HMCR(g) = HMCR0 + (HMCRf - HMCR0) g / G`` and the same for
  PAR, for ``g = 0 .. G-1``.
* Individual selection (eq. 12): the memory member ``t`` is uniform on
  ``0 .. HMS-1`` (the paper's ``round(r3 HMS)`` would reach HMS, one past the end).
* Random bits ``round(r2)`` are fair coin flips.
* Pitch adjustment (eq. 13) applies only to bits taken from memory, as the
  issue describes: such a bit becomes the best harmony's bit with probability PAR.
* Several harmonies are improvised per generation (one per DE trial) from the
  same memory; the memory is then updated with all of them, each replacing the
  current worst member if it is strictly better. Doing so one by one is the same
  as keeping the HMS best of memory and newcomers, with ties won by the members
  already in memory, which is how :func:`update_memory` computes it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["schedule", "improvise", "update_memory"]


def schedule(
    g: int, generations: int, hmcr0: float, hmcrf: float, par0: float, parf: float
) -> tuple[float, float]:
    """HMCR and PAR at generation ``g`` of ``generations`` (eqs. 10a-b)."""
    frac = g / generations if generations > 0 else 0.0
    return hmcr0 + (hmcrf - hmcr0) * frac, par0 + (parf - par0) * frac


def improvise(
    memory: NDArray[np.bool_],
    best: NDArray[np.bool_],
    hmcr: float,
    par: float,
    count: int,
    rng: np.random.Generator,
) -> NDArray[np.bool_]:
    """Improvise ``count`` new binary harmonies (eqs. 12-13).

    Draws one block ``rng.random(count * (3 D + 1))`` and calls :func:`improvise_from_uniforms`.
    """
    d = memory.shape[1]
    return improvise_from_uniforms(memory, best, hmcr, par, rng.random(n_uniforms(count, d)), count)


def n_uniforms(count: int, d: int) -> int:
    """Uniforms consumed by :func:`improvise_from_uniforms`: ``count * (3 D + 1)``."""
    return count * (3 * d + 1)


def improvise_from_uniforms(
    memory: NDArray[np.bool_],
    best: NDArray[np.bool_],
    hmcr: float,
    par: float,
    uniforms: NDArray[np.float64],
    count: int,
) -> NDArray[np.bool_]:
    """Improvise ``count`` harmonies from a block of uniforms on [0, 1).

    For each new harmony one memory member ``t`` is picked; bit ``j`` is
    ``memory[t, j]`` with probability HMCR, else a random bit; each bit taken
    from memory becomes ``best[j]`` with probability PAR.

    Parameters
    ----------
    memory : ndarray of bool, shape (HMS, D)
    best : ndarray of bool, shape (D,)
    hmcr, par : float
    uniforms : ndarray, shape (count * (3 D + 1),)
        In order: member choice (``count``), consideration (``count x D``),
        random bits (``count x D``), pitch adjustment (``count x D``).
    count : int

    Returns
    -------
    ndarray of bool, shape (count, D)
    """
    hms, d = memory.shape
    t = np.minimum((uniforms[:count] * hms).astype(np.intp), hms - 1)
    u3 = uniforms[count : count * (3 * d + 1)].reshape(3, count, d)
    from_memory = u3[0] < hmcr
    new = u3[1] < 0.5
    np.copyto(new, memory[t], where=from_memory)
    np.copyto(new, best[None, :], where=from_memory & (u3[2] < par))
    return new


def update_memory(
    memory: NDArray[np.bool_],
    fitness: NDArray[np.float64],
    new: NDArray[np.bool_],
    new_fitness: NDArray[np.float64],
) -> int:
    """Replace worst members by better newcomers (Step 3), in place.

    Returns
    -------
    int
        Number of newcomers that entered the memory.
    """
    hms = memory.shape[0]
    pool_f = np.concatenate([fitness, new_fitness])
    order = np.argsort(pool_f, kind="stable")[:hms]  # stable: members already in memory win ties
    entered = int(np.count_nonzero(order >= hms))
    if entered:
        pool = np.concatenate([memory, new])
        memory[:] = pool[order]
        fitness[:] = pool_f[order]
    return entered
