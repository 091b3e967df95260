"""A served model run sample by sample, as a controller uses it: :class:`Predictor`.

A controller receives a model (``latest_model``, a ``ModelSubscriber`` callback, ``Model.load``)
and, at every sample, wants the next output (one step ahead) or the outputs over a horizon for the
inputs it plans (a free run: what a model-predictive controller optimises over).  A
:class:`Predictor` keeps the newest measured samples in a bounded buffer, so each call costs the same
however long the loop runs, and a new model can replace the served one between two samples without
losing them (:meth:`Predictor.swap`).

The verbs are river's: :meth:`~Predictor.learn_one` adds the newest measured sample ``(u(t), y(t))``;
:meth:`~Predictor.predict_one` gives ``yhat(t+1)``; :meth:`~Predictor.forecast` gives
``yhat(t+1) .. yhat(t+H)`` for planned inputs ``u(t+1) .. u(t+H)``.  They compute exactly what
:meth:`Model.predict_osa <streamid.engine.model.Model.predict_osa>` and :meth:`Model.simulate
<streamid.engine.model.Model.simulate>` compute on the same samples (tested).  A model with direct terms
(``u(t)``, from ``feedthrough_test``) needs the input at the predicted instant: ``predict_one(u_next)``.

Trust: :meth:`~Predictor.beyond_range` names the signals of the samples a prediction uses (and of a
plan) that leave the model's estimation range by more than
:data:`~streamid.engine.caveats.BEYOND_RANGE` of its span: a Gaussian RBF network does not
extrapolate, so a prediction there is not backed by anything the model saw.

Pure numerics: no clock, no I/O, no threads.  A ``ModelSubscriber`` calls back on a Zenoh thread;
hand its model to the control loop (a queue, or one attribute assignment) and call :meth:`swap` there.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine.caveats import beyond_range
from streamid.engine.model import Model
from streamid.engine.regressors import check_finite
from streamid.errors import DataError

__all__ = ["Predictor", "has_direct_terms", "one_step"]

#: samples a predictor keeps at least (a model swapped in with a longer memory is ready at once up to this)
MIN_HISTORY = 256


def has_direct_terms(model: Model) -> bool:
    """Whether ``model`` uses an input at the predicted instant (a regressor ``u(t)``, lag 0)."""
    nets = getattr(model, "members", None) or (model,)  # an ensemble: any of its networks
    return any(r.signal == "u" and r.lag == 0 for m in nets for r in (*m.regressors, *(m.linear_regressors or ())))


def one_step(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], u_next: ArrayLike | None = None) -> float:
    """``yhat(t+1)`` from the newest ``model.max_lag`` samples ``u`` (L, n_inputs) and ``y`` (L,).

    ``u_next`` is the input at the predicted instant: needed (and used) only by a model with direct terms.
    """
    if u_next is None:
        if has_direct_terms(model):
            raise DataError(f"this model has direct terms (an input at lag 0: {model.lags_text()}); pass u_next, "
                            "the input at the predicted instant")
        nxt = u[-1:] if len(u) else np.zeros((1, model.n_inputs))  # never used: every input lag is >= 1
    else:
        nxt = _inputs("u_next", u_next, model.n_inputs).reshape(1, -1)
    L = model.max_lag
    uu = np.vstack([u[len(u) - L :], nxt])
    yy = np.r_[y[len(y) - L :], y[-1] if len(y) else 0.0]  # the predicted instant's output: never used
    return float(model.predict_osa(uu, yy)[-1])


def _inputs(name: str, value: ArrayLike, n_inputs: int, *, many: bool = False) -> NDArray[np.float64]:
    """``value`` as finite float64: one sample (``n_inputs``,) or, if ``many``, samples (H >= 1, ``n_inputs``)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be numbers; got {value!r}") from None
    if not many:
        a = a.reshape(1) if a.ndim == 0 and n_inputs == 1 else a
        if a.shape != (n_inputs,):
            form = "a number" if n_inputs == 1 else f"a sequence of {n_inputs} numbers (one per input)"
            raise DataError(f"{name} must be {form}; got shape {a.shape}")
    else:
        a = a.reshape(-1, 1) if a.ndim == 1 and n_inputs == 1 else a
        if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] != n_inputs:
            form = "(H,) or (H, 1)" if n_inputs == 1 else f"(H, {n_inputs})"
            raise DataError(f"{name} must be an array of shape {form}, H >= 1 samples; got shape {a.shape}")
    check_finite(name, a)  # names the first NaN or inf: its sample (and column)
    return a


class Predictor:
    """A model run sample by sample from the newest measured samples (see the module docstring).

    Parameters
    ----------
    model
        The model served (any :class:`~streamid.engine.model.Model`: loaded, received, or identified here).

    Holds at most ``2 * max(256, the largest max_lag of the models it served)`` samples.
    """

    def __init__(self, model: Model) -> None:
        self._model = self._checked(model, None)
        self._cap = max(MIN_HISTORY, model.max_lag)
        self._u = np.empty((2 * self._cap, model.n_inputs))
        self._y = np.empty(2 * self._cap)
        self._n = 0  # samples in the buffer (the newest at _n - 1): between _cap and 2 _cap once it has wrapped
        self._held = 0  # samples learnt since the start or the last reset

    # ------------------------------------------------------------------ state
    @property
    def model(self) -> Model:
        """The model served."""
        return self._model

    @property
    def held(self) -> int:
        """Samples held since the start or the last :meth:`reset` (at most the buffer's length)."""
        return min(self._held, self._n)

    @property
    def ready(self) -> bool:
        """Whether ``max_lag`` samples are held: predictions can be made."""
        return self.held >= self._model.max_lag

    def reset(self) -> None:
        """Forget the samples (after a gap in the measurements: a prediction must not span it)."""
        self._n = self._held = 0

    def swap(self, model: Model) -> None:
        """Serve ``model`` from now on, keeping the samples (the model must take the same number of inputs)."""
        model = self._checked(model, self._model)
        if model.max_lag > self._cap:  # a longer memory: keep what is held, in a larger buffer
            u, y = self._recent(self.held)
            self._cap = model.max_lag
            self._u, self._y = np.empty((2 * self._cap, model.n_inputs)), np.empty(2 * self._cap)
            self._n = len(y)
            self._u[: self._n], self._y[: self._n] = u, y
        self._model = model

    # ------------------------------------------------------------------ verbs
    def learn_one(self, u: ArrayLike, y: float) -> None:
        """Add the newest measured sample: the input(s) ``u(t)`` and the output ``y(t)``.

        Raises
        ------
        DataError
            If a value is not a finite number or ``u`` does not hold one value per input; nothing is added.
        """
        ua = _inputs("u", u, self._model.n_inputs)
        ya = _inputs("y", y, 1)[0]
        if self._n == 2 * self._cap:  # full: the newest half moves to the front (amortised O(1) a sample)
            self._u[: self._cap], self._y[: self._cap] = self._u[self._cap :], self._y[self._cap :]
            self._n = self._cap
        self._u[self._n], self._y[self._n] = ua, ya
        self._n += 1
        self._held += 1

    def predict_one(self, u_next: ArrayLike | None = None) -> float:
        """``yhat(t+1)``, the next output one step ahead of the newest sample.

        ``u_next``, the input at the predicted instant, is needed only by a model with direct terms
        (an input at lag 0); any other model ignores it.

        Raises
        ------
        DataError
            If fewer than ``max_lag`` samples are held, or the model needs ``u_next`` and it is missing or bad.
        """
        u, y = self._needed()
        return one_step(self._model, u, y, u_next)

    def forecast(self, u_plan: ArrayLike) -> NDArray[np.float64]:
        """``yhat(t+1) .. yhat(t+H)``: the free run from the newest samples for the planned inputs.

        ``u_plan`` holds ``u(t+1) .. u(t+H)``, shape (H,) or (H, n_inputs).  The run feeds its own
        predictions back (it never sees a measured output after ``t``); with every input lag >= 1 the
        last planned input is not used.

        Raises
        ------
        DataError
            If fewer than ``max_lag`` samples are held, or ``u_plan`` is not finite or of another shape.
        """
        m = self._model
        plan = _inputs("u_plan", u_plan, m.n_inputs, many=True)
        u, y = self._needed()
        L = m.max_lag
        return m.simulate(np.vstack([u, plan]), y)[L:]

    def beyond_range(self, u_plan: ArrayLike | None = None) -> tuple[str, ...]:
        """Names of the signals that leave the model's estimation range by more than
        :data:`~streamid.engine.caveats.BEYOND_RANGE` of its span, in the samples a prediction uses now
        (the newest ``max_lag``) and in ``u_plan`` if given; empty when every one is within."""
        m = self._model
        u, y = self._recent(min(self.held, m.max_lag))
        if u_plan is not None:
            u = np.vstack([u, _inputs("u_plan", u_plan, m.n_inputs, many=True)])
        n = m.normalisation
        out = [name for j, name in enumerate(m.input_names)
               if len(u) and beyond_range(n.u_low[j], n.u_high[j], u[:, j])]
        if len(y) and beyond_range(n.y_low, n.y_high, y):
            out.append(m.output_name)
        return tuple(out)

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _checked(model: Any, current: Model | None) -> Model:
        if not isinstance(model, Model):
            raise DataError(f"a Predictor serves a streamid Model (Model.load, latest_model(...).model); got "
                            f"{type(model).__name__}")
        if current is not None and model.n_inputs != current.n_inputs:
            raise DataError(f"the new model takes {model.n_inputs} input(s) {model.input_names}, the served one "
                            f"{current.n_inputs} {current.input_names}: a Predictor's samples fit one input count")
        return model

    def _recent(self, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self._u[self._n - k : self._n], self._y[self._n - k : self._n]

    def _needed(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        L = self._model.max_lag
        if self.held < L:
            raise DataError(f"this model needs the newest {L} samples (max_lag) before it predicts; "
                            f"{self.held} held since the start or the last reset")
        return self._recent(L)
