r"""A model made of several RBF networks: the mean of its members (``streamid.model/3``; ``/5`` when a member
has a long linear part).

Prediction formula (all a reader needs to reproduce predictions from the file)
-------------------------------------------------------------------------------
The document holds ``members``, each one network as in ``streamid.model/1`` / ``/2``
(its own ``regressors``, ``centres``, ``widths``, ``weights`` and optional ``linear``
part), and ONE ``normalisation`` shared by all of them. With ``F_i`` member ``i``'s
network in normalised units (:mod:`streamid.model.narx`'s formula) and ``K`` members::

    one step ahead:  yn(t) = (1/K) sum_i F_i(r_i(t))          r_i from MEASURED past outputs
    free run:        yn_i(t) = F_i(r_i(t))                     r_i from member i's OWN past outputs
                     yn(t)   = (1/K) sum_i yn_i(t)
    y(t) = (yn(t) + 1) (y_high - y_low) / 2 + y_low

In free run every member simulates on its own past predictions (from the same measured
initial outputs) and the members' outputs are averaged: the averaged output is never fed
back (that would be another model). Because the output scale is affine, averaging in
normalised or in output units gives the same numbers (to rounding; streamid averages in
output units, each member's output mapped back first).

``max_lag`` is the largest lag of any member: one-step-ahead and free-run arrays hold the
measured outputs in their first ``max_lag`` samples; member ``i`` starts its free run from
the first ``max_lag_i`` of them. ``lags`` / ``lags_text`` describe the union of the members'
lags (each member's own are in :meth:`EnsembleModel.summary` and the document); ``neurons``
is the members' neurons summed.

An :class:`EnsembleModel` is a :class:`~streamid.model.narx.Model` (every consumer of a
model predicts, simulates, saves and loads it the same way). Its single-network fields
(``regressors``, ``centres``, ``widths``, ``weights``, ``linear``, ``linear_regressors``) are its FIRST member's
(the best ranked); the operations that work on one network's internals --
:meth:`regressor_rows`, :func:`~streamid.engine.choice.complexity.pruned`,
:func:`~streamid.engine.choice.scores.group_free_run`
-- refuse an ensemble with a :class:`~streamid.errors.ModelFormatError` saying so;
:func:`~streamid.engine.choice.selection.refit_weights` refits every member.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model.narx import (
    MODEL_FORMAT_ENSEMBLE, MODEL_FORMAT_ENSEMBLE_LONG_LINEAR, MODEL_FORMAT_ENSEMBLE_MEDIAN, Model, _finite_array,
    initial_outputs)
from streamid.model.uncertainty import Interval
from streamid.model.limits import CHUNK_ROWS, check_model_document
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import DataError, ModelFormatError
from streamid.threads import thread_map

__all__ = ["COMBINES", "EnsembleModel", "MAX_MEMBERS", "MODEL_FORMAT_ENSEMBLE", "ensemble_of", "members_of"]

#: How an ensemble combines its members' outputs: their mean (``streamid.model/3``, ``/5``) or their per-sample median
#: (``/6``: one member that leaves the next waveform moves the median little, the mean a lot; docs/method.md).
COMBINES = ("mean", "median")

#: Most members an ensemble holds (each costs a network's evaluation: a document from elsewhere is bounded
#: by this and by the wire's document size). The engine's "all admissible runs" ensemble takes the top ones.
MAX_MEMBERS = 32

_MEMBER_FORM = ("an object with regressors, centres (M x k), widths (M), weights (M) and optionally linear (k + 1; "
                "in a streamid.model/5 document, with linear_regressors, one number per linear regressor, then the constant)")


def members_of(model: Model) -> tuple[Model, ...]:
    """The networks of ``model``: its members for an ensemble, ``(model,)`` for a single network."""
    return model.members if isinstance(model, EnsembleModel) else (model,)


def ensemble_of(members: Sequence[Model], **fields: Any) -> Model:
    """The mean of ``members`` (an :class:`EnsembleModel`), or the one network itself when there is one.

    ``fields``: ``metrics``, ``window``, ``config``, ``input_names``, ``output_name`` (default: the
    first member's). The members' own metrics, windows and configs are not kept (the document holds one of each).
    """
    if len(members) == 1:
        return replace(members[0], **fields) if fields else members[0]
    return EnsembleModel.of(members, **fields)


@dataclass(frozen=True, eq=False)
class EnsembleModel(Model):
    """The mean of several Gaussian RBF networks (see the module docstring for the formula).

    Attributes
    ----------
    members : tuple of Model
        The networks (>= 2, none an ensemble), best ranked first; each is given this model's
        normalisation and names. The inherited single-network fields are the first member's.

    Raises
    ------
    ModelFormatError
        Fewer than 2 members, a member that is not a single network, or inputs that disagree.
    """

    #: The document formats this class reads (:meth:`Model.from_dict` hands them to it).
    READS: ClassVar[tuple[str, ...]] = (MODEL_FORMAT_ENSEMBLE, MODEL_FORMAT_ENSEMBLE_LONG_LINEAR,
                                        MODEL_FORMAT_ENSEMBLE_MEDIAN)

    members: tuple[Model, ...] = ()
    combine: str = "mean"

    @classmethod
    def of(cls, members: Sequence[Model], **fields: Any) -> EnsembleModel:
        """An ensemble of ``members`` (their first's normalisation and names unless given in ``fields``)."""
        if not members:
            raise ModelFormatError(f"model field 'members' must be a list of 2 to {MAX_MEMBERS} networks ({_MEMBER_FORM}); got none")
        m0 = members[0]
        base = {"regressors": m0.regressors, "centres": m0.centres, "widths": m0.widths, "weights": m0.weights,
                "linear": m0.linear, "linear_regressors": m0.linear_regressors, "normalisation": m0.normalisation, "input_names": m0.input_names,
                "output_name": m0.output_name}
        return cls(**{**base, **fields, "members": tuple(members)})

    def __post_init__(self) -> None:
        if self.combine not in COMBINES:
            raise ModelFormatError(f"an ensemble's combine must be one of {', '.join(COMBINES)}; got {self.combine!r}")
        ms = self.members
        if not isinstance(ms, tuple) or not 2 <= len(ms) <= MAX_MEMBERS:
            raise ModelFormatError(
                f"model field 'members' must be a list of 2 to {MAX_MEMBERS} networks ({_MEMBER_FORM}); got {len(ms) if isinstance(ms, tuple) else ms!r} "
                "(a single network is a streamid.model/1 or /2 document)")
        for i, m in enumerate(ms):
            if not isinstance(m, Model) or isinstance(m, EnsembleModel):
                raise ModelFormatError(f"model field 'members[{i}]' must be a single network ({_MEMBER_FORM}); got {type(m).__name__}")
            if m.normalisation.n_inputs != self.normalisation.n_inputs:
                raise ModelFormatError(f"model field 'members[{i}]' has {m.normalisation.n_inputs} input(s); "
                                       f"the ensemble has {self.normalisation.n_inputs} (one normalisation for all members)")
        # One normalisation and one set of names: the ensemble's (a recalibration replaces the ensemble's
        # normalisation, and every member follows). Members carry no metrics, window or config of their own.
        synced = tuple(m if (m.normalisation == self.normalisation and m.input_names == self.input_names
                             and m.output_name == self.output_name and not m.metrics and not m.window and not m.config)
                       else replace(m, normalisation=self.normalisation, input_names=self.input_names or m.input_names,
                                    output_name=self.output_name, metrics={}, window={}, config={})
                       for m in ms)
        object.__setattr__(self, "members", synced)
        m0 = synced[0]  # the single-network fields are always the first member's
        for name in ("regressors", "centres", "widths", "weights", "linear", "linear_regressors"):
            object.__setattr__(self, name, getattr(m0, name))
        super().__post_init__()

    # ------------------------------------------------------------------ structure
    @property
    def neurons(self) -> int:
        """The members' neurons summed."""
        return sum(m.neurons for m in self.members)

    @property
    def max_lag(self) -> int:
        """Largest lag of any member: samples needed before the first prediction."""
        return max(m.max_lag for m in self.members)

    def _union(self) -> tuple[Regressor, ...]:
        regs = {r for m in self.members for r in m.regressors}
        return tuple(sorted(regs, key=lambda r: (r.signal != "y", r.index, r.lag)))

    @property
    def lags(self) -> dict[str, Any]:
        """The union of the members' lags ``{"y": [...], "u": [[...] per input]}`` (each member's: ``members[i].lags``)."""
        regs = self._union()
        return {"y": [r.lag for r in regs if r.signal == "y"],
                "u": [[r.lag for r in regs if r.signal == "u" and r.index == i] for i in range(self.n_inputs)]}

    def labels(self) -> list[str]:
        """Readable names of the union of the members' regressors."""
        return [r.label(self.input_names, self.output_name) for r in self._union()]

    def summary(self) -> str:
        """Like :meth:`Model.summary`, saying it is a mean of N networks, with each member's lags and size."""
        lines = Model.summary(self).splitlines()
        sizes = ", ".join(f"{m.neurons}" + (" + linear" if m.linear is not None else "") for m in self.members)
        if any(m.linear_regressors is not None for m in self.members):  # Model.summary's "linear part" line: member 0's
            lines = [ln.replace("  linear part ", "  linear part (member 0's) ") for ln in lines]
        lines[0] = f"RBF-NARX ensemble ({self.combine} of {len(self.members)} networks) {', '.join(self.input_names)} -> {self.output_name}"
        lines[1] = f"  regressors  {self.lags_text()}  (union of the members', max lag {self.max_lag})"
        lines[2] = f"  network     {self.combine} of {len(self.members)} networks of {sizes} Gaussian neurons ({self.neurons} in all)"
        for i, m in enumerate(self.members):
            own = f" and a linear part of {len(m.linear_regressors)} terms of its own" if m.linear_regressors is not None else ""
            lines.insert(3 + i, f"  member {i}    {m.lags_text()}, {m.neurons} neurons{own}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"<EnsembleModel {self.output_name} = {self.combine} of {len(self.members)} networks on F[{self.lags_text()}], "
                f"{self.neurons} neurons; model.summary() describes it, model.to_json() holds every number>")

    # ------------------------------------------------------------------ prediction
    def regressor_rows(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raise ModelFormatError("an ensemble has no single regressor matrix (each member has its own lags): "
                               "use model.members[i].regressor_rows")

    def _phi(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        raise ModelFormatError("an ensemble has no single activation matrix: use model.members[i]")

    def predict_osa(self, u: ArrayLike, y: ArrayLike, threads: int = 1) -> NDArray[np.float64]:
        """One-step-ahead: the mean of the members' predictions from measured past outputs (see the module docstring);
        ``threads``: the members computed in that many threads (the same values to the bit)."""
        ua, ya = self._check(u, y)
        L = self.max_lag
        out = ya.copy()
        n = ya.shape[0]
        if n - L <= CHUNK_ROWS:  # up to one chunk: every member over the whole record at once
            out[L:] = self._combined(np.array(thread_map(lambda m: m.predict_osa(ua, ya)[L:], self.members, threads)))
            return out

        def block(a: int) -> None:  # beyond: a chunk of rows at a time (memory of a chunk, not K records)
            b = min(n, a + CHUNK_ROWS)
            out[a:b] = self._combined(np.array([m.predict_osa(ua[a - L : b], ya[a - L : b])[L:] for m in self.members]))

        thread_map(block, range(L, n, CHUNK_ROWS), threads)
        return out

    def combine_rows(self, rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """The members' outputs ``rows`` (K, n) at the same samples combined as the model combines them (their mean
        or per-sample median): e.g. a piece of :func:`~streamid.model.freerun.chunked_paths`."""
        return self._combined(rows)

    def _combined(self, rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """The members' outputs ``rows`` (K, n) combined: their mean or their per-sample median."""
        out: NDArray[np.float64] = np.median(rows, axis=0) if self.combine == "median" else np.mean(rows, axis=0)
        return out

    def simulate_many(self, runs: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[NDArray[np.float64]]:
        """Free runs: each member simulates on its own past outputs, the outputs averaged (module docstring).

        Each run's ``y_init`` must hold at least :attr:`max_lag` measured outputs; member ``i`` starts
        from the first ``members[i].max_lag`` of them. The first ``max_lag`` values returned are measured.
        """
        L = self.max_lag
        inits = [initial_outputs(y_init, L) for _, y_init in runs]
        if not inits:
            return []
        per_member = [m.simulate_many(runs) for m in self.members]
        out = []
        for c, yi in enumerate(inits):
            avg = self._combined(np.array([sims[c] for sims in per_member]))
            avg[:L] = yi[:L]
            out.append(avg)
        return out

    def member_paths(self, u: ArrayLike, y_init: ArrayLike) -> NDArray[np.float64]:
        """Each member's free run (rows), from its own past outputs; the first :attr:`max_lag` samples measured."""
        L = self.max_lag
        yi = initial_outputs(y_init, L)
        try:
            n = int(np.shape(u)[0])
        except (IndexError, TypeError):
            raise DataError(f"u must have shape (N,) or (N, n_inputs); got {u!r}") from None
        paths = np.empty((len(self.members), n))  # filled in place: no second copy of K records
        for i, m in enumerate(self.members):
            paths[i] = m.simulate(u, yi)
        paths[:, :L] = yi[:L]
        return paths

    def combine_paths(self, paths: NDArray[np.float64], y_init: ArrayLike) -> NDArray[np.float64]:
        """The ensemble's free run from its members' (:meth:`member_paths`), as :meth:`simulate_many` makes it."""
        out = self._combined(paths)
        out[: self.max_lag] = paths[0, : self.max_lag]
        return out

    def map_members(self, fn: Callable[[Model], Model], **fields: Any) -> EnsembleModel:
        """The same ensemble with ``fn`` applied to every member (e.g. a refit), ``fields`` replaced."""
        return replace(self, members=tuple(fn(m) for m in self.members), **fields)

    # ------------------------------------------------------------------ file format
    def to_dict(self) -> dict[str, Any]:
        """The ``streamid.model/3`` JSON document as a dict (``/5`` when a member has a long linear part, its
        ``linear_regressors`` then in the member; docs/wire-format.md)."""
        members = []
        for m in self.members:
            d = m.to_dict()
            member = {k: d[k] for k in ("regressors", "lags", "max_lag", "centres", "widths", "weights")}
            if m.linear is not None:
                member["linear"] = d["linear"]
            if m.linear_regressors is not None:
                member["linear_regressors"] = d["linear_regressors"]
            members.append(member)
        long_linear = any(m.linear_regressors is not None for m in self.members)
        median = self.combine == "median"
        doc: dict[str, Any] = {
            "format": (MODEL_FORMAT_ENSEMBLE_MEDIAN if median else
                       MODEL_FORMAT_ENSEMBLE_LONG_LINEAR if long_linear else MODEL_FORMAT_ENSEMBLE),
            "kind": "gaussian-rbf-narx-ensemble",
            "formula": (
                "yn_i(t) = sum_m members[i].weights[m] * exp(-sum_j (r_ij(t) - members[i].centres[m][j])^2 / "
                "(2 members[i].widths[m]^2)) [+ sum_j members[i].linear[j] r_ij(t) + members[i].linear[k_i]]; "
                "r_ij(t) = normalised members[i].signal_j(t - lag_j): measured past outputs one step ahead, "
                "member i's own past yn_i in free run; yn = " + ("median" if median else "mean") + "_i yn_i; x_n = 2 (x - low)/(high - low) - 1; "
                "y = (yn + 1) (y_high - y_low)/2 + y_low"
                + ("; a member with linear_regressors has the linear part sum_q members[i].linear[q] l_iq(t) + "
                   "members[i].linear[-1] instead, l_iq(t) = normalised signal_q(t - lag_q) of members[i].linear_regressors[q]"
                   if long_linear else "")
            ),
            "inputs": list(self.input_names),
            "output": self.output_name,
            "lags": self.lags,
            "max_lag": self.max_lag,
            "normalisation": self.normalisation.to_dict(),
            "members": members,
            "metrics": self.metrics,
            "window": self.window,
            "config": self.config,
        }
        if median:
            doc["combine"] = "median"
        if self.interval is not None:
            doc["interval"] = self.interval.to_dict()
        return doc

    @classmethod
    def from_dict(cls, d: Any) -> EnsembleModel:
        """Inverse of :meth:`to_dict`; raises :class:`ModelFormatError` naming the field on anything invalid."""
        if not isinstance(d, Mapping):
            raise ModelFormatError(f"a model document must be a JSON object; got {type(d).__name__}")
        fmt = d.get("format")
        if fmt not in cls.READS:
            raise ModelFormatError(f"model 'format' must be one of {', '.join(repr(f) for f in cls.READS)} for an "
                                   f"ensemble; got {fmt!r}")
        median = fmt == MODEL_FORMAT_ENSEMBLE_MEDIAN
        if d.get("combine", "median" if median else "mean") != ("median" if median else "mean"):
            raise ModelFormatError(f"model field 'combine' must be {'median' if median else 'mean'!r} in a {fmt} "
                                   f"document (the format says how the members combine); got {d.get('combine')!r}")
        check_model_document(d)  # neurons, regressors, lags, parameters: before any array is built
        raw = d.get("members")
        if not isinstance(raw, list) or not 2 <= len(raw) <= MAX_MEMBERS:
            got = f"{len(raw)} member(s)" if isinstance(raw, list) else repr(raw)[:200]
            raise ModelFormatError(f"model field 'members' must be a list of 2 to {MAX_MEMBERS} networks ({_MEMBER_FORM}); got {got}")
        try:
            norm = Normalisation.from_dict(d["normalisation"])
        except KeyError:
            raise ModelFormatError("model field 'normalisation' is missing (one normalisation shared by the members)") from None
        names = tuple(str(s) for s in d.get("inputs", ()))
        output = str(d.get("output", "y"))
        members = [_member(i, e, norm, names, output, fmt != MODEL_FORMAT_ENSEMBLE) for i, e in enumerate(raw)]
        if fmt == MODEL_FORMAT_ENSEMBLE_LONG_LINEAR and all(m.linear_regressors is None for m in members):
            raise ModelFormatError(f"a {MODEL_FORMAT_ENSEMBLE_LONG_LINEAR} document has at least one member with "
                                   f"'linear_regressors' (a long linear part); got none (an ensemble of networks is "
                                   f"{MODEL_FORMAT_ENSEMBLE})")
        try:
            return cls.of(members, normalisation=norm, input_names=names or members[0].input_names, output_name=output,
                          metrics=dict(d.get("metrics", {})), window=dict(d.get("window", {})),
                          config=dict(d.get("config", {})), combine="median" if median else "mean",
                          interval=Interval.from_dict(d["interval"]) if "interval" in d else None)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ModelFormatError):
                raise
            raise ModelFormatError(f"model fields 'metrics', 'window', 'config' must be JSON objects ({exc})") from None


def _member(i: int, e: Any, norm: Normalisation, names: tuple[str, ...], output: str, long_linear: bool) -> Model:
    """Member ``i`` of a ``streamid.model/3`` (``long_linear`` False) or ``/5`` document (errors name
    ``members[i].<field>``)."""
    where = f"members[{i}]"
    if not isinstance(e, Mapping):
        raise ModelFormatError(f"model field {where!r} must be {_MEMBER_FORM}; got {type(e).__name__}")
    lregs: tuple[Regressor, ...] | None = None
    if "linear_regressors" in e:
        if not long_linear:
            raise ModelFormatError(f"model field '{where}.linear_regressors' (a long linear part) is allowed only in a "
                                   f"{MODEL_FORMAT_ENSEMBLE_LONG_LINEAR} document; this one is {MODEL_FORMAT_ENSEMBLE}")
        lregs = _regressor_list(e, where, "linear_regressors")
        if "linear" not in e:
            raise ModelFormatError(f"model field '{where}.linear' is missing: a member with linear_regressors needs "
                                   f"one coefficient per linear regressor, then the constant ({len(lregs) + 1} numbers)")
    regs = _regressor_list(e, where, "regressors")
    try:
        widths = e["widths"]
        m = len(widths)
        lin = e.get("linear")
        return Model(
            regressors=regs,
            centres=_finite_array(f"{where}.centres", e["centres"] if regs else [[]] * m, (m, len(regs))),
            widths=_finite_array(f"{where}.widths", widths, (m,)),
            weights=_finite_array(f"{where}.weights", e["weights"], (m,)),
            normalisation=norm, input_names=names, output_name=output,
            linear=None if lin is None else _finite_array(f"{where}.linear", lin, (len(regs if lregs is None else lregs) + 1,)),
            linear_regressors=lregs,
        )
    except ModelFormatError as exc:
        msg = str(exc)
        raise ModelFormatError(msg if where in msg else f"{where}: {msg}") from None
    except (KeyError, TypeError) as exc:
        raise ModelFormatError(f"model field {where!r} is missing or has a malformed field ({type(exc).__name__}: {exc}); "
                               f"expected {_MEMBER_FORM}") from None



def _regressor_list(e: Mapping[str, Any], where: str, field: str) -> tuple[Regressor, ...]:
    """Member field ``field`` (a list of ``{signal, index, lag}``) of member ``where``."""
    try:
        return tuple(Regressor(str(r["signal"]), int(r["index"]), int(r["lag"])) for r in e[field])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFormatError(f"model field '{where}.{field}' must be a list of {{signal, index, lag}}; "
                               f"({type(exc).__name__}: {exc})") from None
