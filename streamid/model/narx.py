r"""The identified model: prediction, free-run simulation and its JSON file.

Prediction formula (all a reader needs to reproduce predictions from the file)
-------------------------------------------------------------------------------
With ``norm`` the file's ``normalisation`` (``x_n = 2 (x - low) / (high - low) - 1``
per signal, ``u_low[i]``/``u_high[i]`` for input ``i``, ``y_low``/``y_high`` for the
output) and ``regressors`` the ordered list of ``{"signal", "index", "lag"}``::

    r_j(t)  = norm(signal_j)(t - lag_j)                  j = 0 .. k-1   (y or input ``index``)
    phi_m   = exp(-sum_j (r_j(t) - centres[m][j])^2 / (2 widths[m]^2))
    yn(t)   = sum_m weights[m] phi_m  [+ sum_j linear[j] r_j(t) + linear[k]]
    y(t)    = (yn(t) + 1) (y_high - y_low) / 2 + y_low

The bracketed direct linear part (an "RBF network with linear terms") exists only in
documents of format ``streamid.model/2`` (field ``linear``: k coefficients, then the
constant); a ``streamid.model/1`` document has none (it is the same as ``linear = 0``).
A model without a linear part is always written as ``streamid.model/1``, so readers
of the first format keep reading every model they can evaluate correctly.

A *long* linear part has regressors of its own (``streamid.model/4``, field
``linear_regressors``, in the form of ``regressors``; ``linear`` then has one
coefficient per linear regressor, then the constant)::

    yn(t)   = sum_m weights[m] phi_m + sum_i linear[i] l_i(t) + linear[q]
    l_i(t)  = norm(signal_i)(t - lag_i)                  i = 0 .. q-1   (the linear regressors)

It is a dense linear ARX part of an order chosen from the data, for devices whose
memory is longer than the network's lags (:mod:`streamid.engine.choice.longlinear`).

One-step-ahead prediction uses measured past outputs; free run (simulation)
uses the model's own past predictions after ``max_lag`` measured initial outputs.
Both return arrays aligned with the input whose first ``max_lag`` values are the
measured outputs given (no prediction exists there).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model.freerun import free_run
from streamid.threads import thread_map
from streamid.model.describe import describe
from streamid.model.domain import far_from_domain
from streamid.model.files import read_model_file
from streamid.model.limits import CHUNK_ROWS, MIN_WIDTH, check_model_document, osa_block_rows, parse_model_json
from streamid.model.regressors import Normalisation, Regressor, as_data, check_finite, format_lags, regressor_columns
from streamid.model.uncertainty import Band, Interval
from streamid.errors import DataError, ModelFormatError

__all__ = ["Model", "MODEL_FORMAT", "MODEL_FORMAT_ENSEMBLE", "MODEL_FORMAT_ENSEMBLE_LONG_LINEAR", "MODEL_FORMAT_ENSEMBLE_MEDIAN", "MODEL_FORMAT_LINEAR",
           "MODEL_FORMAT_LONG_LINEAR",
           "MODEL_FORMATS", "free_run", "format_lags"]

MODEL_FORMAT = "streamid.model/1"
#: The format of a model with a direct linear part (``linear``); /1 documents load as ``linear = None``.
MODEL_FORMAT_LINEAR = "streamid.model/2"
#: The format of the mean of several networks (:mod:`streamid.model.ensemble`); loads as an ``EnsembleModel``.
MODEL_FORMAT_ENSEMBLE = "streamid.model/3"
#: The format of a model whose linear part has regressors of its own (``linear_regressors``: a long linear part).
MODEL_FORMAT_LONG_LINEAR = "streamid.model/4"
#: The format of the mean of several networks of which at least one has a long linear part (``/3``'s layout, a member
#: then also holding ``linear_regressors``); loads as an ``EnsembleModel``. A ``/3`` reader refuses it by its format.
MODEL_FORMAT_ENSEMBLE_LONG_LINEAR = "streamid.model/5"
#: The format of the per-sample median of several networks (members as in ``/5``, a long linear part allowed); loads
#: as an ``EnsembleModel`` whose ``combine`` is ``"median"``. A reader of ``/3`` or ``/5`` refuses it by its format.
MODEL_FORMAT_ENSEMBLE_MEDIAN = "streamid.model/6"
MODEL_FORMATS = (MODEL_FORMAT, MODEL_FORMAT_LINEAR, MODEL_FORMAT_ENSEMBLE, MODEL_FORMAT_LONG_LINEAR,
                 MODEL_FORMAT_ENSEMBLE_LONG_LINEAR, MODEL_FORMAT_ENSEMBLE_MEDIAN)


#: Rows of a one-step-ahead prediction computed at once: its regressors and activations take about 900 bytes a row
#: (30 lags, 30 neurons), so a block is ~60 MB whatever the record's length (a 380,000-sample piezo record took
#: 336 MB at once).
OSA_BLOCK_ROWS = CHUNK_ROWS

def _finite_array(name: str, value: Any, shape: tuple[int, ...]) -> NDArray[np.float64]:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelFormatError(f"model field {name!r} must be an array of numbers of shape {shape}; got {value!r}") from None
    if a.shape != shape:
        raise ModelFormatError(f"model field {name!r} must have shape {shape}; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelFormatError(f"model field {name!r} must contain only finite numbers (no NaN/inf); got {value!r}")
    return a


def initial_outputs(y_init: ArrayLike, max_lag: int) -> NDArray[np.float64]:
    """A free run's ``y_init`` as a flat float array of at least ``max_lag`` samples, or a :class:`DataError`."""
    try:
        yi = np.asarray(y_init, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DataError(f"y_init must be an array of numbers; got {y_init!r}") from None
    if yi.size < max_lag:
        raise DataError(f"y_init must hold at least max_lag = {max_lag} samples; got {yi.size}")
    return yi


def _reader_of(fmt: str) -> type[Model]:
    """The subclass of :class:`Model` that reads documents of format ``fmt`` (its ``READS``): the ensembles'
    :class:`~streamid.model.ensemble.EnsembleModel`, which the package ``streamid.model`` always defines
    before any of its modules is used, so this module never imports the one that builds on it."""
    for sub in Model.__subclasses__():
        if fmt in getattr(sub, "READS", ()):
            return sub
    raise ModelFormatError(f"no reader for model format {fmt!r} is loaded (import streamid.model)")


@dataclass(frozen=True, eq=False)
class Model:
    """A Gaussian RBF NARX model (see the module docstring for the formula).

    Attributes
    ----------
    regressors : tuple of Regressor
        Selected lagged terms, in the order of the centre coordinates.
    centres : ndarray, shape (M, k)
    widths : ndarray, shape (M,)
    weights : ndarray, shape (M,)
    normalisation : Normalisation
    input_names : tuple of str
    output_name : str
    metrics : dict
        Fitness and validation figures (JSON-able).
    window : dict
        The data the model was fitted on (sample count, indices/times when known).
    config : dict
        The :class:`~streamid.engine.settings.CoEAConfig` used (as a dict).
    linear : ndarray, shape (k + 1,), optional
        Direct linear part: a coefficient per regressor (normalised units), then the
        constant. None: no linear part (the paper's network).
    linear_regressors : tuple of Regressor, optional
        The linear part's own regressors (a long linear part); ``linear`` then has shape
        ``(len(linear_regressors) + 1,)``. None: the linear part (if any) is on ``regressors``.
    interval : Interval, optional
        What the free-run prediction interval needs (:mod:`~streamid.model.uncertainty`); None: the model
        carries none (it was identified without calibration data, or by an earlier streamid).

    Raises
    ------
    ModelFormatError
        If any parameter is not finite or the shapes disagree (a Model never holds NaN).
    """

    regressors: tuple[Regressor, ...]
    centres: NDArray[np.float64]
    widths: NDArray[np.float64]
    weights: NDArray[np.float64]
    normalisation: Normalisation
    input_names: tuple[str, ...] = ()
    output_name: str = "y"
    metrics: dict[str, Any] = field(default_factory=dict)
    window: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    linear: NDArray[np.float64] | None = None
    linear_regressors: tuple[Regressor, ...] | None = None
    interval: Interval | None = None

    def __post_init__(self) -> None:
        m = int(np.shape(self.widths)[0]) if np.ndim(self.widths) == 1 else -1
        k = len(self.regressors)
        if m < 1:
            raise ModelFormatError(f"model widths must be a 1-D array with >= 1 neuron; got shape {np.shape(self.widths)}")
        object.__setattr__(self, "centres", _finite_array("centres", self.centres, (m, k)))
        object.__setattr__(self, "widths", _finite_array("widths", self.widths, (m,)))
        object.__setattr__(self, "weights", _finite_array("weights", self.weights, (m,)))
        if np.any(self.widths < MIN_WIDTH):
            bad = int(np.argmin(self.widths))
            raise ModelFormatError(f"model widths must be > 0, at least {MIN_WIDTH:g} (1 / (2 w^2) must be a finite float64); "
                                   f"got {float(self.widths[bad])!r} at neuron {bad}")
        n_in = self.normalisation.n_inputs
        if self.linear_regressors is not None and self.linear is None:
            raise ModelFormatError("model linear_regressors need a linear part (their coefficients, then the constant)")
        for r in (*self.regressors, *(self.linear_regressors or ())):
            ok = (r.signal == "y" and r.index == 0) or (r.signal == "u" and 0 <= r.index < n_in)
            if not ok or r.lag < (1 if r.signal == "y" else 0):
                raise ModelFormatError(
                    f"regressor {r} must be signal 'y' (index 0) with lag >= 1 or 'u' (index 0..{n_in - 1}) with lag >= 0"
                )
        if not self.input_names:
            object.__setattr__(self, "input_names", tuple(f"u{i}" for i in range(n_in)))
        if len(self.input_names) != n_in:
            raise ModelFormatError(f"model has {n_in} inputs but {len(self.input_names)} input names {self.input_names}")
        for key, val in self.metrics.items():
            if isinstance(val, float) and not math.isfinite(val):
                raise ModelFormatError(f"model metric {key!r} must be finite; got {val!r}")
        if self.linear is not None:
            q = k if self.linear_regressors is None else len(self.linear_regressors)
            object.__setattr__(self, "linear", _finite_array("linear", self.linear, (q + 1,)))
            self.linear.setflags(write=False)
        for c in self.centres, self.widths, self.weights:
            c.setflags(write=False)

    # ------------------------------------------------------------------ structure
    @property
    def n_inputs(self) -> int:
        return self.normalisation.n_inputs

    @property
    def neurons(self) -> int:
        return int(self.widths.shape[0])

    @property
    def max_lag(self) -> int:
        """Largest selected lag (of the network and of a long linear part): samples needed before the first prediction."""
        return max((r.lag for r in (*self.regressors, *(self.linear_regressors or ()))), default=0)

    @property
    def linear_order(self) -> int:
        """Order of a dense linear ARX part (the largest lag of ``linear_regressors``); 0 without one."""
        return max((r.lag for r in self.linear_regressors or ()), default=0)

    @property
    def lags(self) -> dict[str, Any]:
        """Selected lags ``{"y": [...], "u": [[...] per input]}``."""
        return {
            "y": [r.lag for r in self.regressors if r.signal == "y"],
            "u": [[r.lag for r in self.regressors if r.signal == "u" and r.index == i] for i in range(self.n_inputs)],
        }

    def lags_text(self) -> str:
        """The selected lags in streamid's one vocabulary, e.g. ``force_N(t-1,t-2) velocity_cm_s(t-1..t-3)``.

        See :func:`format_lags`.
        """
        lags = self.lags
        return format_lags(self.output_name, lags["y"], self.input_names, lags["u"])

    def summary(self) -> str:
        """A short readable description: signals with their lags, neurons, metrics (a few lines).

        ``str(model)`` and ``print(model)`` give the same text; ``to_json`` gives every number.
        """
        return describe(self)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return (
            f"<Model {self.output_name} = F[{self.lags_text()}], {self.neurons} neurons; "
            "model.summary() describes it, model.to_json() holds every number>"
        )

    def labels(self) -> list[str]:
        """Readable names of the regressors, e.g. ``['y(t-1)', 'u(t-1)']``."""
        return [r.label(self.input_names, self.output_name) for r in self.regressors]

    # ------------------------------------------------------------------ prediction
    def _check(self, u: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        ua, ya = as_data(u, y, min_samples=self.max_lag + 1)
        if ua.shape[1] != self.n_inputs:
            raise DataError(f"the model has {self.n_inputs} input(s); got u with {ua.shape[1]} column(s)")
        return ua, ya

    def _phi(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        from streamid.model.kernels import scaled_distances  # numba, loaded on the first prediction (not on import)

        d2 = np.empty((r.shape[0], self.neurons))
        c = np.ascontiguousarray(self.centres)
        scaled_distances(np.ascontiguousarray(r), c, -(2.0 * self.widths**2), d2)  # -d2 / (2 w^2)
        return np.exp(d2, out=d2)

    def regressor_rows(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The normalised regressors of rows ``t >= max_lag`` (one column per regressor) and the normalised targets.

        ``u`` of shape (N, n_inputs) and ``y`` of shape (N,), as :meth:`_check` returns them.
        """
        L = self.max_lag
        un, yn = self.normalisation.u(u), self.normalisation.y(y)
        return regressor_columns(self.regressors, un, yn, L), yn[L:]

    def linear_rows(self, u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        """The normalised regressors of the linear part for rows ``t >= max_lag`` (its own, or the network's)."""
        regs = self.regressors if self.linear_regressors is None else self.linear_regressors
        return regressor_columns(regs, self.normalisation.u(u), self.normalisation.y(y), self.max_lag)

    def predict_osa(self, u: ArrayLike, y: ArrayLike, threads: int = 1) -> NDArray[np.float64]:
        """One-step-ahead prediction from measured inputs and outputs.

        Parameters
        ----------
        u : array_like, shape (N,) or (N, n_inputs)
        y : array_like, shape (N,)
        threads : int
            The record's blocks in that many threads (``streamid validate``'s cores): the same values to the bit.

        Returns
        -------
        ndarray, shape (N,)
            ``yhat[t]`` for ``t >= max_lag``; the first ``max_lag`` values are ``y``'s.
        """
        ua, ya = self._check(u, y)
        out = ya.copy()
        L = self.max_lag
        rows = osa_block_rows(self.neurons, len(self.regressors), OSA_BLOCK_ROWS)

        def block(a: int) -> None:  # rows a..b-1 from samples a-L..b-1: bounded memory
            b = min(ya.shape[0], a + rows)
            us, ys = ua[a - L : b], ya[a - L : b]
            r, _ = self.regressor_rows(us, ys)
            yn_hat = self._phi(r) @ self.weights
            if self.linear is not None:
                rl = r if self.linear_regressors is None else self.linear_rows(us, ys)
                yn_hat += rl @ self.linear[:-1] + self.linear[-1]
            out[a:b] = self.normalisation.y_inverse(yn_hat)

        thread_map(block, range(L, ya.shape[0], rows), threads)
        return out

    @overload
    def simulate(self, u: ArrayLike, y_init: ArrayLike, interval: None = None) -> NDArray[np.float64]: ...

    @overload
    def simulate(self, u: ArrayLike, y_init: ArrayLike, interval: float) -> Band: ...

    def simulate(self, u: ArrayLike, y_init: ArrayLike, interval: float | None = None) -> NDArray[np.float64] | Band:
        """Free run: recursive simulation on the model's own past outputs.

        Parameters
        ----------
        u : array_like, shape (N,) or (N, n_inputs)
        y_init : array_like
            At least ``max_lag`` measured outputs: the first ``max_lag`` samples.
            (A full-length measured output may be passed; only its start is used.)
        interval : float, optional
            A level of the model's prediction interval (one of ``model.interval.levels``, e.g. 0.9): then the
            free run comes with the band's lower and upper paths (:class:`~streamid.model.uncertainty.Band`).

        Returns
        -------
        ndarray, shape (N,), or Band of three
            First ``max_lag`` values from ``y_init``, then the simulated outputs (and, with ``interval``, the band:
            of width zero over the measured initial outputs).
        """
        if interval is None:
            return self.simulate_many([(u, y_init)])[0]
        if self.interval is None:
            raise DataError("this model carries no prediction interval (identified without calibration data, or by "
                            "an earlier streamid): simulate without interval=, or identify it again")
        paths = self.member_paths(u, y_init)
        centre = self.combine_paths(paths, y_init)
        return self.interval.band(centre, paths, float(interval), self.max_lag, far_from_domain(self, u, centre))

    def member_paths(self, u: ArrayLike, y_init: ArrayLike) -> NDArray[np.float64]:
        """The free runs of the model's networks, shape ``(K, N)``: one row for a single network, a member's each
        for an ensemble (each from its own past outputs; the first ``max_lag`` samples measured)."""
        return self.simulate_many([(u, y_init)])[0][None, :]

    def combine_paths(self, paths: NDArray[np.float64], y_init: ArrayLike) -> NDArray[np.float64]:
        """The model's free run from its networks' (:meth:`member_paths`): the one network's path itself."""
        return np.array(paths[0])

    def simulate_many(self, runs: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[NDArray[np.float64]]:
        """Several free runs of this model at once, e.g. on the estimation and the validation data.

        Equal to ``[self.simulate(u, y_init) for u, y_init in runs]`` (to rounding), in one
        recursion over the longest input: the runs advance together, so two runs cost
        about as much as the longer one alone.

        Parameters
        ----------
        runs : sequence of (u, y_init)
            As for :meth:`simulate`.

        Returns
        -------
        list of ndarray
            One array per run, shaped like its ``u``'s first axis.
        """
        L = self.max_lag
        parts: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        for u, y_init in runs:
            yi = initial_outputs(y_init, L)
            try:
                n_u = int(np.shape(u)[0])
            except (IndexError, TypeError):
                raise DataError(f"u must have shape (N,) or (N, n_inputs); got {u!r}") from None
            ua, _ = self._check(u, np.zeros(n_u))
            check_finite("y_init", yi[:L])
            parts.append((ua, yi[:L]))
        if not parts:
            return []
        n = max(ua.shape[0] for ua, _ in parts)
        un = np.zeros((len(parts), n, self.n_inputs))  # shorter runs padded (their tails are discarded)
        for c, (ua, _) in enumerate(parts):
            un[c, : ua.shape[0]] = self.normalisation.u(ua)
        C = len(parts)
        yn = free_run(
            self.regressors,
            np.broadcast_to(self.centres, (C, *self.centres.shape)),
            np.broadcast_to(self.widths, (C, self.neurons)),
            np.broadcast_to(self.weights, (C, self.neurons)),
            un,
            np.stack([self.normalisation.y(yi) for _, yi in parts]),
            None if self.linear is None else np.broadcast_to(self.linear, (C, self.linear.shape[0])),
            linear_regressors=self.linear_regressors,
        )
        out = []
        for c, (ua, yi) in enumerate(parts):
            sim = self.normalisation.y_inverse(yn[c, : ua.shape[0]])
            sim[:L] = yi
            out.append(sim)
        return out

    # ------------------------------------------------------------------ file format
    def to_dict(self) -> dict[str, Any]:
        """The JSON document as a dict (see :meth:`to_json`)."""
        fmt = MODEL_FORMAT if self.linear is None else MODEL_FORMAT_LINEAR
        doc: dict[str, Any] = {
            "format": MODEL_FORMAT_LONG_LINEAR if self.linear_regressors is not None else fmt,
            "kind": "gaussian-rbf-narx",
            "formula": (
                "yn(t) = sum_m weights[m] * exp(-sum_j (r_j(t) - centres[m][j])^2 / (2 widths[m]^2)); "
                "r_j(t) = normalised signal_j(t - lag_j); x_n = 2 (x - low)/(high - low) - 1; "
                "y = (yn + 1) (y_high - y_low)/2 + y_low"
            ),
            "inputs": list(self.input_names),
            "output": self.output_name,
            "regressors": [
                {**r.to_dict(), "name": r.label(self.input_names, self.output_name)} for r in self.regressors
            ],
            "lags": self.lags,
            "max_lag": self.max_lag,
            "normalisation": self.normalisation.to_dict(),
            "centres": self.centres.tolist(),
            "widths": self.widths.tolist(),
            "weights": self.weights.tolist(),
            "metrics": self.metrics,
            "window": self.window,
            "config": self.config,
        }
        if self.linear is not None:
            doc["formula"] = str(doc["formula"]).replace(
                "(2 widths[m]^2));", "(2 widths[m]^2)) + sum_j linear[j] r_j(t) + linear[k];")
            doc["linear"] = self.linear.tolist()
        if self.linear_regressors is not None:
            doc["formula"] = str(doc["formula"]).replace(
                "sum_j linear[j] r_j(t) + linear[k];",
                "sum_i linear[i] l_i(t) + linear[q]; l_i(t) = normalised signal_i(t - lag_i) of linear_regressors[i];")
            doc["linear_regressors"] = [
                {**r.to_dict(), "name": r.label(self.input_names, self.output_name)} for r in self.linear_regressors]
        if self.interval is not None:
            doc["interval"] = self.interval.to_dict()
        return doc

    def to_json(self, indent: int | None = 1) -> str:
        """Serialise to the versioned JSON format ``streamid.model/1`` (never pickle)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    @classmethod
    def from_dict(cls, d: Any) -> Model:
        """Inverse of :meth:`to_dict`; raises :class:`ModelFormatError` on anything invalid."""
        if not isinstance(d, Mapping):
            raise ModelFormatError(f"a model document must be a JSON object; got {type(d).__name__}")
        fmt = d.get("format")
        if fmt not in MODEL_FORMATS:
            raise ModelFormatError(f"model 'format' must be one of {list(MODEL_FORMATS)}; got {fmt!r}")
        check_model_document(d)  # neurons, regressors, lags, parameters: before any array is built
        if fmt in (MODEL_FORMAT_ENSEMBLE, MODEL_FORMAT_ENSEMBLE_LONG_LINEAR, MODEL_FORMAT_ENSEMBLE_MEDIAN):  # the mean of several networks (a Model too)
            return _reader_of(fmt).from_dict(d)
        if fmt == MODEL_FORMAT_LINEAR and "linear" not in d:
            raise ModelFormatError(f"a {MODEL_FORMAT_LINEAR} model document needs the field 'linear' (k + 1 numbers)")
        if fmt == MODEL_FORMAT_LONG_LINEAR and not ("linear" in d and isinstance(d.get("linear_regressors"), list)):
            raise ModelFormatError(f"a {MODEL_FORMAT_LONG_LINEAR} model document needs the fields 'linear_regressors' "
                                   "(a list of {signal, index, lag}) and 'linear' (one number each, then the constant)")
        try:
            regs = tuple(Regressor(str(r["signal"]), int(r["index"]), int(r["lag"])) for r in d["regressors"])
            lregs = (tuple(Regressor(str(r["signal"]), int(r["index"]), int(r["lag"])) for r in d["linear_regressors"])
                     if fmt == MODEL_FORMAT_LONG_LINEAR else None)
            widths = d["widths"]
            m = len(widths)
            return cls(
                regressors=regs,
                centres=_finite_array("centres", d["centres"] if regs else [[]] * m, (m, len(regs))),
                widths=_finite_array("widths", widths, (m,)),
                weights=_finite_array("weights", d["weights"], (m,)),
                normalisation=Normalisation.from_dict(d["normalisation"]),
                input_names=tuple(str(s) for s in d.get("inputs", ())),
                output_name=str(d.get("output", "y")),
                metrics=dict(d.get("metrics", {})),
                window=dict(d.get("window", {})),
                config=dict(d.get("config", {})),
                linear=(_finite_array("linear", d["linear"], (len(regs if lregs is None else lregs) + 1,))
                        if fmt in (MODEL_FORMAT_LINEAR, MODEL_FORMAT_LONG_LINEAR) else None),
                linear_regressors=lregs,
                interval=Interval.from_dict(d["interval"]) if "interval" in d else None,
            )
        except ModelFormatError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(
                f"model document is missing or has a malformed field ({type(exc).__name__}: {exc}); "
                f"expected the {MODEL_FORMAT} fields regressors, centres, widths, weights, normalisation"
            ) from None

    @classmethod
    def from_json(cls, text: str | bytes) -> Model:
        """Parse a ``streamid.model/1`` JSON document (size and nesting bounded: :mod:`~streamid.model.limits`)."""
        return cls.from_dict(parse_model_json(text, "a model file"))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model's JSON file (``streamid.model/1``) to ``path``; returns the path.

        The file is written whole or not at all (a temporary file renamed into place).
        """
        target = Path(path)
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_text(self.to_json(), encoding="utf-8")
        os.replace(tmp, target)
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Model:
        """Read a model JSON file written by :meth:`save`, ``streamid identify --model`` or the daemon.

        A daemon's model-update document (``streamid.model-update/1``) is accepted too: its
        ``model`` field is read.

        Raises
        ------
        ModelFormatError
            If the file is missing, not JSON, or not a valid model document (the message names the file).
        """
        p = Path(path)
        d = read_model_file(p, MODEL_FORMATS)
        try:
            return cls.from_dict(d)
        except ModelFormatError as exc:
            raise ModelFormatError(f"{p}: {exc}") from None

    def with_metrics(self, **metrics: Any) -> Model:
        """A copy with metrics added (values must be finite)."""
        from dataclasses import replace

        return replace(self, metrics={**self.metrics, **metrics})
