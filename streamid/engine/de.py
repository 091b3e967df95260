"""Differential Evolution DE/rand/1/bin (paper section 3.1, eqs. 7-9) as pure functions.

Every random draw comes from the :class:`numpy.random.Generator` passed in.
The functions accept optional ``out`` buffers so that a run can reuse its
memory every generation; results do not depend on whether buffers are given.

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
    """DE/rand/1/bin trials from one block of uniforms, with preallocated buffers.

    ``maker(x, uniforms)`` with ``uniforms`` of length :meth:`n_uniforms`
    (donor keys ``NP*NP``, crossover ``NP*D``, ``j_rand`` ``NP``, in that order)
    returns the trial population in a buffer overwritten by the next call.
    """

    def __init__(self, size: int, dim: int, lo: NDArray[np.float64], hi: NDArray[np.float64], f: float, cr: float):
        if size < 4:
            raise ValueError(f"DE/rand/1 needs a population of at least 4; got {size}")
        self.size, self.dim = size, dim
        self.f, self.cr = float(f), float(cr)
        self.lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (dim,)).copy()
        self.hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (dim,)).copy()
        self.lo2, self.hi2 = 2.0 * self.lo, 2.0 * self.hi
        self.clip = self.f > 1.0
        self._v = np.empty((size, dim))
        self._d = np.empty((size, dim))
        self._u = np.empty((size, dim))
        self._tmp = np.empty((size, dim))

    @staticmethod
    def n_uniforms(size: int, dim: int) -> int:
        """Uniforms consumed per call: ``NP * (NP + D + 1)``."""
        return size * (size + dim + 1)

    def __call__(self, x: NDArray[np.float64], uniforms: NDArray[np.float64]) -> NDArray[np.float64]:
        n, d = self.size, self.dim
        keys = uniforms[: n * n].reshape(n, n)
        cross = uniforms[n * n : n * (n + d)].reshape(n, d)
        jr = uniforms[n * (n + d) : n * (n + d + 1)]
        idx = donors_from_keys(keys)
        v, dd, u, tmp = self._v, self._d, self._u, self._tmp
        np.take(x, idx[:, 0], axis=0, out=v)
        np.take(x, idx[:, 1], axis=0, out=dd)
        np.subtract(dd, np.take(x, idx[:, 2], axis=0, out=tmp), out=dd)
        dd *= self.f
        v += dd
        take = crossover_mask(cross, jr, self.cr)
        np.copyto(u, x)
        np.copyto(u, v, where=take)
        np.subtract(self.lo2, u, out=tmp)
        np.maximum(u, tmp, out=u)
        np.subtract(self.hi2, u, out=tmp)
        np.minimum(u, tmp, out=u)
        if self.clip:
            np.clip(u, self.lo, self.hi, out=u)
        return u


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
    x[better] = u[better]
    fx[better] = fu[better]
    return better
