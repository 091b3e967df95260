"""Differential Evolution DE/rand/1/bin (paper section 3.1, eqs. 7-9) as pure functions.

Every random draw comes from the :class:`numpy.random.Generator` passed in.
The functions accept optional ``out`` buffers so that a run can reuse its
memory every generation; results do not depend on whether buffers are given.
A run uses :class:`TrialMaker`, which turns the uniforms of a whole block of
generations into donor indices and crossover masks at once and then makes each
generation's trials with a handful of array operations; it gives exactly the
trials of the pure functions below on the same uniforms (tested).

Choices left open by the paper, as streamid makes them
------------------------------------------------------
* Donors ``r1, r2, r3`` are distinct and different from the target ``i``
  (Table 1), drawn uniformly (the three smallest of ``NP`` uniform keys with the
  target's key excluded).
* Binomial crossover takes coordinate ``j`` from the mutant when ``rand < CR``
  and, as in Storn & Price's DE/rand/1/bin, always at one random coordinate
  ``j_rand`` so that a trial never equals its target.
* Trials outside the search box are reflected back at the violated bound
  (``2 lo - v`` below ``lo``, ``2 hi - v`` above ``hi``), then clipped. With
  ``F <= 1`` a mutant is never more than one box width outside, so the
  reflection alone lands inside; the clip only matters for ``F > 1``.
  Reflection keeps the search's density near the bounds without piling
  members on them.
* Selection is greedy with strict improvement (eq. 9): a trial replaces its
  target only if its fitness is lower.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["donors", "mutate", "crossover", "reflect", "trials", "select"]


def donors(rng: np.random.Generator, size: int) -> NDArray[np.intp]:
    """Indices ``(size, 3)``: for each target ``i`` three distinct members, all ``!= i``.

    Draws ``rng.random((size, size))`` and calls :func:`donors_from_keys`.
    """
    if size < 4:
        raise ValueError(f"DE/rand/1 needs a population of at least 4; got {size}")
    return donors_from_keys(rng.random((size, size)))


def donors_from_keys(keys: NDArray[np.float64]) -> NDArray[np.intp]:
    """Donors from uniform keys ``(NP, NP)``: row ``i``'s three smallest keys, column ``i`` excluded.

    ``keys`` is modified (its diagonal is set to 2). Row ``i`` of the result
    holds ``r1, r2, r3`` (in no particular order; their roles are symmetric in
    distribution).
    """
    np.fill_diagonal(keys, 2.0)  # the target itself is never among the three smallest
    return np.argpartition(keys, 2, axis=1)[:, :3]


def mutate(
    x: NDArray[np.float64], idx: NDArray[np.intp], f: float, out: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Mutant vectors ``v_i = x_r1 + F (x_r2 - x_r3)`` (eq. 7), with ``idx[i] = (r1, r2, r3)``."""
    v = np.take(x, idx[:, 0], axis=0, out=out)
    v += f * (x[idx[:, 1]] - x[idx[:, 2]])
    return v


def crossover_mask(cross_u: NDArray[np.float64], jrand_u: NDArray[np.float64], cr: float) -> NDArray[np.bool_]:
    """Which coordinates a trial takes from its mutant: ``cross_u < CR``, plus ``j_rand = floor(jrand_u D)``.

    Parameters
    ----------
    cross_u : ndarray, shape (NP, D)
        Uniforms on [0, 1).
    jrand_u : ndarray, shape (NP,)
        Uniforms on [0, 1) choosing the forced coordinate.
    cr : float
    """
    n, d = cross_u.shape
    take = cross_u < cr
    j = np.minimum((jrand_u * d).astype(np.intp), d - 1)
    take[np.arange(n), j] = True
    return take


def crossover(
    x: NDArray[np.float64],
    v: NDArray[np.float64],
    cr: float,
    rng: np.random.Generator,
    out: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Binomial crossover (eq. 8) with one forced mutant coordinate ``j_rand`` per trial.

    Draws ``rng.random((NP, D + 1))``: the crossover uniforms, then the ``j_rand`` uniform.
    """
    n, d = x.shape
    uni = rng.random((n, d + 1))
    take = crossover_mask(uni[:, :d], uni[:, d], cr)
    if out is None:
        return np.where(take, v, x)
    np.copyto(out, x)
    np.copyto(out, v, where=take)
    return out


def reflect(t: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bring coordinates back inside ``[lo, hi]``: reflection at the violated bound, then clipping.

    ``max(t, 2 lo - t)`` is ``t`` inside and the reflection ``2 lo - t`` below ``lo``
    (likewise ``min(t, 2 hi - t)`` above ``hi``); a value still outside after both
    reflections (more than a box width out) is clipped. Works in place and returns ``t``.
    """
    np.maximum(t, 2.0 * lo - t, out=t)
    np.minimum(t, 2.0 * hi - t, out=t)
    np.clip(t, lo, hi, out=t)
    return t


def trials(
    x: NDArray[np.float64],
    f: float,
    cr: float,
    lo: NDArray[np.float64],
    hi: NDArray[np.float64],
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """One generation of DE/rand/1/bin trial vectors for the whole population.

    Parameters
    ----------
    x : ndarray, shape (NP, D)
        Current population.
    f, cr : float
        Scale factor and crossover probability.
    lo, hi : ndarray, shape (D,) or scalars
        Search box.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (NP, D)
        Trial vectors inside the box. Draws one block ``rng.random(NP * (NP + D + 1))``:
        donor keys, crossover uniforms, ``j_rand`` uniforms (see :class:`TrialMaker`).
    """
    n, d = x.shape
    return TrialMaker(n, d, lo, hi, f, cr)(x, rng.random(TrialMaker.n_uniforms(n, d)))


class TrialMaker:
    """DE/rand/1/bin trials from blocks of uniforms, with preallocated buffers.

    The random numbers of a block of ``B`` generations are turned into donor
    indices and crossover masks at once (:meth:`plan`: one ``argpartition`` over
    the ``(B, NP, NP)`` donor keys, one comparison for the ``(B, NP, D)``
    crossover uniforms), so that a generation's trials (:meth:`make`) cost one
    gather of the three donors, the mutation, one masked copy (crossover) and the
    reflection. Generation ``k`` of a block uses row ``k`` of the uniforms,
    ``NP*NP`` donor keys, ``NP*D`` crossover uniforms and ``NP`` ``j_rand``
    uniforms, in that order (:meth:`n_uniforms` per generation), exactly as
    :func:`donors_from_keys`, :func:`mutate`, :func:`crossover_mask` and
    :func:`reflect` would use them one generation at a time.

    ``maker(x, uniforms)`` makes one generation's trials from a flat block of
    :meth:`n_uniforms` uniforms. Trials are returned in a buffer overwritten by
    the next call.
    """

    def __init__(
        self,
        size: int,
        dim: int,
        lo: NDArray[np.float64],
        hi: NDArray[np.float64],
        f: float,
        cr: float,
        block: int = 1,
    ):
        if size < 4:
            raise ValueError(f"DE/rand/1 needs a population of at least 4; got {size}")
        self.size, self.dim, self.block = size, dim, max(1, int(block))
        self.f, self.cr = float(f), float(cr)
        self.lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (dim,)).copy()
        self.hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (dim,)).copy()
        self.lo2, self.hi2 = 2.0 * self.lo, 2.0 * self.hi
        self.clip = self.f > 1.0
        self._v = np.empty((size, dim))
        self._tmp = np.empty((size, dim))
        self._idx = np.empty((self.block, 3, size), dtype=np.intp)  # per generation: r1, r2, r3 rows
        self._keep = np.empty((self.block, size, dim), dtype=bool)  # per generation: NOT from the mutant
        self._diag = np.arange(size)
        self._planned = 0

    @staticmethod
    def n_uniforms(size: int, dim: int) -> int:
        """Uniforms consumed per generation: ``NP * (NP + D + 1)``."""
        return size * (size + dim + 1)

    def plan(self, uniforms: NDArray[np.float64]) -> int:
        """Donors and crossover masks of ``B = uniforms.shape[0]`` generations (``B <= block``).

        ``uniforms`` has shape ``(B, >= n_uniforms)`` (extra columns are ignored);
        its donor-key columns are modified (diagonals set to 2). Returns ``B``.
        """
        n, d = self.size, self.dim
        b: int = uniforms.shape[0]
        if b > self.block:
            raise ValueError(f"at most {self.block} generations per plan; got {b}")
        keys = uniforms[:, : n * n].reshape(b, n, n)
        keys[:, self._diag, self._diag] = 2.0  # the target itself is never among the three smallest
        idx = np.argpartition(keys, 2, axis=2)[:, :, :3]  # row-wise, as donors_from_keys
        np.copyto(self._idx[:b], idx.transpose(0, 2, 1))
        keep = self._keep[:b]
        np.greater_equal(uniforms[:, n * n : n * (n + d)].reshape(b, n, d), self.cr, out=keep)
        j = np.minimum((uniforms[:, n * (n + d) : n * (n + d + 1)] * d).astype(np.intp), d - 1)
        keep.reshape(b * n, d)[np.arange(b * n), j.ravel()] = False  # j_rand: always from the mutant
        self._planned = b
        return b

    def make(self, x: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        """Trials of generation ``k`` of the current plan for population ``x`` (NP, D)."""
        v, tmp = self._v, self._tmp
        x3 = x[self._idx[k]]  # (3, NP, D); fancy indexing is ~2x faster than take(out=) here
        np.subtract(x3[1], x3[2], out=tmp)  # v = x_r1 + F (x_r2 - x_r3), as mutate
        tmp *= self.f
        np.add(x3[0], tmp, out=v)
        np.putmask(v, self._keep[k], x)  # binomial crossover: target's coordinate where not crossed
        np.subtract(self.lo2, v, out=tmp)  # reflection, as reflect
        np.maximum(v, tmp, out=v)
        np.subtract(self.hi2, v, out=tmp)
        np.minimum(v, tmp, out=v)
        if self.clip:
            np.clip(v, self.lo, self.hi, out=v)
        return v

    def __call__(self, x: NDArray[np.float64], uniforms: NDArray[np.float64]) -> NDArray[np.float64]:
        """One generation's trials from a flat block of :meth:`n_uniforms` uniforms."""
        self.plan(np.asarray(uniforms, dtype=np.float64).reshape(1, -1))
        return self.make(x, 0)


def select(
    x: NDArray[np.float64], fx: NDArray[np.float64], u: NDArray[np.float64], fu: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """Greedy selection (eq. 9), in place: ``x_i <- u_i`` where ``f(u_i) < f(x_i)``.

    Returns
    -------
    ndarray of bool, shape (NP,)
        Which members were replaced.
    """
    better = fu < fx
    np.copyto(x, u, where=better[:, None])
    np.copyto(fx, fu, where=better)
    return better
