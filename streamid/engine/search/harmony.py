"""Adaptive Binary Harmony Search with individual selection (paper section 3.2, eqs. 10-13).

Pure functions; every random draw comes from the Generator passed in.
:class:`Improviser` is the block form a run uses: the masks of a block of
generations are prepared at once, and a generation's harmonies then cost one
gather and two masked copies (same result as :func:`improvise_from_uniforms`).

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

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Improviser", "improvise", "improvise_from_uniforms", "schedule", "update_memory"]


def schedule(g: Any, generations: int, hmcr: tuple[float, float], par: tuple[float, float]) -> tuple[Any, Any]:
    """HMCR and PAR at generation ``g`` of ``generations`` (eqs. 10a-b), each moved linearly from its pair's
    first value to its second (:data:`~streamid.engine.settings.HMCR`, :data:`~streamid.engine.settings.PAR`);
    ``g`` an int (floats returned) or an array of generations (arrays returned)."""
    frac = g / generations if generations > 0 else 0.0 * g
    return hmcr[0] + (hmcr[1] - hmcr[0]) * frac, par[0] + (par[1] - par[0]) * frac


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
    new: NDArray[np.bool_] = u3[1] < 0.5
    np.copyto(new, memory[t], where=from_memory)
    np.copyto(new, best[None, :], where=from_memory & (u3[2] < par))
    return new


class Improviser:
    """Improvisation from blocks of uniforms, with preallocated buffers.

    :meth:`plan` turns the uniforms of ``B`` generations (row ``k``: the layout of
    :func:`improvise_from_uniforms`) and their HMCR/PAR into member indices,
    consideration, random-bit and pitch-adjustment masks at once; :meth:`make`
    then improvises generation ``k``'s harmonies from the memory and best harmony
    of that moment with one gather and two masked copies. The result equals
    :func:`improvise_from_uniforms` on the same uniforms; it is returned in a
    buffer overwritten by the next call.
    """

    def __init__(self, hms: int, d: int, count: int, block: int = 1) -> None:
        self.hms, self.d, self.count, self.block = hms, d, count, max(1, int(block))
        self._t = np.empty((self.block, count), dtype=np.intp)
        self._consider = np.empty((self.block, count, d), dtype=bool)
        self._bits = np.empty((self.block, count, d), dtype=bool)
        self._pitch = np.empty((self.block, count, d), dtype=bool)
        self._new = np.empty((count, d), dtype=bool)

    def plan(self, uniforms: NDArray[np.float64], hmcr: NDArray[np.float64], par: NDArray[np.float64]) -> int:
        """Prepare ``B = uniforms.shape[0]`` generations; ``hmcr``, ``par`` of shape ``(B,)``. Returns ``B``."""
        c, d, hms = self.count, self.d, self.hms
        b: int = uniforms.shape[0]
        if b > self.block:
            raise ValueError(f"at most {self.block} generations per plan; got {b}")
        np.minimum((uniforms[:, :c] * hms).astype(np.intp), hms - 1, out=self._t[:b])
        u3 = uniforms[:, c : c * (3 * d + 1)].reshape(b, 3, c, d)
        consider = self._consider[:b]
        np.less(u3[:, 0], hmcr[:, None, None], out=consider)
        np.less(u3[:, 1], 0.5, out=self._bits[:b])
        pitch = self._pitch[:b]
        np.less(u3[:, 2], par[:, None, None], out=pitch)
        pitch &= consider
        return b

    def make(self, memory: NDArray[np.bool_], best: NDArray[np.bool_], k: int) -> NDArray[np.bool_]:
        """Harmonies of generation ``k`` of the current plan."""
        new = self._new
        np.copyto(new, self._bits[k])
        np.copyto(new, memory[self._t[k]], where=self._consider[k])
        np.copyto(new, best, where=self._pitch[k])
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
    if new_fitness.min() >= fitness.max():  # nobody beats the worst member (NaN: full path below)
        return 0
    pool_f = np.concatenate([fitness, new_fitness])
    order = pool_f.argsort(kind="stable")[:hms]  # stable: members already in memory win ties
    entered = int((order >= hms).sum())
    if entered:
        pool = np.concatenate([memory, new])
        memory[:] = pool[order]
        fitness[:] = pool_f[order]
    return entered
