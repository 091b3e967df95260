"""A served model run sample by sample, as a controller uses it: :class:`Predictor`.

A controller receives a model (``latest_model``, a ``ModelSubscriber`` callback, ``Model.load``)
and, at every sample, wants the next output (one step ahead) or the outputs over a horizon for the
inputs it plans (a free run: what a model-predictive controller optimises over).  A
:class:`Predictor` keeps the newest measured samples in a bounded buffer, so each call costs the same
however long the loop runs, and a new model can replace the served one between two samples without
losing them (:meth:`Predictor.swap`).

The verbs are river's: :meth:`~Predictor.learn_one` adds the newest measured sample ``(u(t), y(t))``;
:meth:`~Predictor.predict_one` gives ``yhat(t+1)``; :meth:`~Predictor.forecast` gives
``yhat(t+1) .. yhat(t+H)`` for planned inputs ``u(t+1) .. u(t+H)``, :meth:`~Predictor.forecast_many` the
same for several candidate plans at once.  They compute exactly what
:meth:`Model.predict_osa <streamid.model.narx.Model.predict_osa>` and :meth:`Model.simulate
<streamid.model.narx.Model.simulate>` compute on the same samples (tested).  A model with direct terms
(``u(t)``, from ``direct_terms``) needs the input at the predicted instant: ``predict_one(u_next)``.

:meth:`~Predictor.step` runs the model as a simulator, one instant a call, as an FMU's ``doStep`` or the generated
C code's ``<name>_step`` does: from the newest measured samples, ``step(u(t+1))``, ``step(u(t+2))``, ... give the
free run's :class:`~streamid.model.stepping.Step` of each instant (``y``, the band's ``lower`` and ``upper`` at the
level asked, ``in_domain``), what ``forecast(plan, interval=level)`` gives for the plan of those inputs, computed
as :meth:`Model.simulate <streamid.model.narx.Model.simulate>` computes it (an ensemble's members each on their own
outputs, the band's spread and growth beyond the domain: :mod:`~streamid.model.stepping`), at a fixed cost an
instant. The run never sees a measured output: :meth:`~Predictor.learn_one` (a measurement), :meth:`~Predictor.swap`
and :meth:`~Predictor.reset` end it, and the next ``step`` starts again from the newest measured samples. A
simulator run in parallel with the device (never corrected) is a second predictor given only its first
``max_lag`` samples::

    sim = Predictor(model)
    for u_k, y_k in first_samples:      # max_lag measured samples
        sim.learn_one(u_k, y_k)
    for u_k in inputs:                  # then inputs only
        s = sim.step(u_k)               # s.y, s.lower, s.upper (90 % band), s.in_domain

Trust: :meth:`~Predictor.beyond_range` names the signals of the samples a prediction uses (and of a
plan) that leave the model's estimation range by more than
:data:`~streamid.model.domain.BEYOND_RANGE` of its span: a Gaussian RBF network does not
extrapolate, so a prediction there is not backed by anything the model saw.

Each sample costs the same small, fixed work: the predictor keeps the samples also in the served model's
normalised units and prepares each network once (:class:`_Network`: where each regressor sits in the buffer,
the centres and widths in the order it gathers them), so :meth:`~Predictor.predict_one` gathers one row and
evaluates one Gaussian layer, with none of :meth:`Model.predict_osa
<streamid.model.narx.Model.predict_osa>`'s checks of whole arrays (``streamid bench --only engine``, "controller
loop").

Pure numerics: no clock, no I/O, no threads.  A ``ModelSubscriber`` calls back on a Zenoh thread;
hand its model to the control loop (a queue, or one attribute assignment) and call :meth:`swap` there.
"""

from __future__ import annotations

from math import isfinite
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model.kernels import one_row
from streamid.model.domain import beyond_range, outside
from streamid.model.ensemble import EnsembleModel, members_of
from streamid.model.narx import Model
from streamid.model.limits import MAX_INPUTS, MAX_LAG, MAX_NEURONS
from streamid.model.regressors import Normalisation, Regressor
from streamid.model.regressors import check_finite
from streamid.model.stepping import FreeRun, Step, band_quantile
from streamid.model.uncertainty import DEFAULT_LEVEL, Band
from streamid.errors import DataError

__all__ = ["Predictor", "Step", "has_direct_terms", "one_step"]

#: samples a predictor keeps at least (a model swapped in with a longer memory is ready at once up to this)
MIN_HISTORY = 256


def has_direct_terms(model: Model) -> bool:
    """Whether ``model`` uses an input at the predicted instant (a regressor ``u(t)``, lag 0)."""
    return any(r.signal == "u" and r.lag == 0
               for m in members_of(model) for r in (*m.regressors, *(m.linear_regressors or ())))


def _u_next_missing(model: Model) -> DataError:
    return DataError(f"this model has direct terms (an input at lag 0: {model.lags_text()}); pass u_next, "
                     "the input at the predicted instant")


def one_step(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], u_next: ArrayLike | None = None) -> float:
    """``yhat(t+1)`` from the newest ``model.max_lag`` samples ``u`` (L, n_inputs) and ``y`` (L,).

    ``u_next`` is the input at the predicted instant: needed (and used) only by a model with direct terms.
    """
    if u_next is None:
        if has_direct_terms(model):
            raise _u_next_missing(model)
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


class _Network:
    """One network of a served model, prepared for one row at a time (what ``predict_osa`` computes for it).

    Its regressors are gathered y's first, then the inputs' (the centres' columns and the linear coefficients
    permuted to match: a sum in another order, equal to rounding); a lag ``l`` reads the sample ``l`` before
    the predicted instant, so a direct term (``l`` = 0) reads the slot after the newest sample, where
    :meth:`Predictor.predict_one` puts ``u_next``.
    """

    __slots__ = ("y_lags", "u_lags", "u_cols", "centres", "two_w2", "weights", "lin", "lin_const", "lin_own",
                 "ly_lags", "lu_lags", "lu_cols")

    def __init__(self, net: Model) -> None:
        self.y_lags, self.u_lags, self.u_cols, order = self._gather(net.regressors)
        self.centres = np.ascontiguousarray(net.centres[:, order])
        self.two_w2 = 2.0 * net.widths**2  # predict_osa's denominator, computed as it does
        self.weights = np.ascontiguousarray(net.weights)
        self.lin = np.empty(0)  # no linear part
        self.lin_const = 0.0
        self.lin_own = net.linear_regressors is not None
        self.ly_lags, self.lu_lags, self.lu_cols = self.y_lags, self.u_lags, self.u_cols
        if net.linear is not None:
            lin_order = order
            if net.linear_regressors is not None:
                self.ly_lags, self.lu_lags, self.lu_cols, lin_order = self._gather(net.linear_regressors)
            self.lin, self.lin_const = np.ascontiguousarray(net.linear[:-1][lin_order]), float(net.linear[-1])

    @staticmethod
    def _gather(regs: tuple[Regressor, ...]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                                                       NDArray[np.intp]]:
        ys = [j for j, r in enumerate(regs) if r.signal == "y"]
        us = [j for j, r in enumerate(regs) if r.signal == "u"]
        return (np.array([regs[j].lag for j in ys], dtype=np.int64), np.array([regs[j].lag for j in us], dtype=np.int64),
                np.array([regs[j].index for j in us], dtype=np.int64), np.array(ys + us, dtype=np.intp))

    def yn(self, un: NDArray[np.float64], yn: NDArray[np.float64], n: int) -> float:
        """The network's normalised output at the instant ``n`` (samples ``n - lag`` of ``un`` and ``yn``)."""
        return float(one_row(un, yn, n, self.y_lags, self.u_lags, self.u_cols, self.centres, self.two_w2,
                             self.weights, self.lin, self.lin_const, self.ly_lags, self.lu_lags, self.lu_cols,
                             self.lin_own))


class Predictor:
    """A model run sample by sample from the newest measured samples (see the module docstring).

    Parameters
    ----------
    model
        The model served (any :class:`~streamid.model.narx.Model`: loaded, received, or identified here).

    Holds at most ``2 * max(256, the largest max_lag of the models it served)`` samples.  The first
    predictor of a process loads the compiled one-step kernel (about 0.2 s; about 1 s once per install, when
    numba compiles it), so a control loop built after it pays nothing of that at its first sample.
    """

    def __init__(self, model: Model) -> None:
        self._model = self._checked(model, None)
        self._cap = max(MIN_HISTORY, model.max_lag)
        self._n = 0  # samples in the buffer (the newest at _n - 1): between _cap and 2 _cap once it has wrapped
        self._held = 0  # samples learnt since the start or the last reset
        self._running = False  # whether step()'s free run (self._run) has started from the newest measured samples
        self._alloc(model.n_inputs)
        self._serve(model)
        self._nets[0].yn(self._un, self._yn, self._lag)  # load (or compile) the kernel now; the value is unused

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

    @property
    def stepped(self) -> int:
        """Instants :meth:`step` has simulated since its free run started from the newest measured samples (0:
        the next :meth:`step` starts one)."""
        return self._run.steps if self._running else 0

    def reset(self) -> None:
        """Forget the samples and any free run (after a gap in the measurements: a prediction must not span it)."""
        self._n = self._held = 0
        self._running = False

    def swap(self, model: Model) -> None:
        """Serve ``model`` from now on, keeping the samples (the model must take the same number of inputs); the
        next :meth:`step` starts the new model's free run from the newest measured samples."""
        model = self._checked(model, self._model)
        if model.max_lag > self._cap:  # a longer memory: keep what is held, in a larger buffer
            u, y = (a.copy() for a in self._recent(self.held))
            self._cap = model.max_lag
            self._alloc(model.n_inputs)
            self._n = len(y)
            self._u[: self._n], self._y[: self._n] = u, y
        self._serve(model)

    # ------------------------------------------------------------------ verbs
    def learn_one(self, u: ArrayLike, y: float) -> None:
        """Add the newest measured sample: the input(s) ``u(t)`` and the output ``y(t)``; the next :meth:`step`
        starts a free run from it (a measurement ends the free run of the earlier ones).

        Raises
        ------
        DataError
            If a value is not a finite number or ``u`` does not hold one value per input; nothing is added.
        """
        # one input given as a float (the common loop) is checked in Python, anything else by _inputs: the same
        # values either way, and a refused sample changes nothing
        u_row: float | NDArray[np.float64]
        if self._scalar_u and isinstance(u, float) and isinstance(y, float) and isfinite(u) and isfinite(y):
            # Normalisation.u and .y, sample by sample (the same operations: the same values)
            u_row, un_row = u, 2.0 * (u - self._u_low0) / self._u_span0 - 1.0
        else:
            u_row = _inputs("u", u, self._model.n_inputs)
            un_row = 2.0 * (u_row - self._u_low) / self._u_span - 1.0
            y = _inputs("y", y, 1)[0]
        n = self._n
        if n == 2 * self._cap:  # full: the newest half moves to the front (amortised O(1) a sample)
            c = self._cap
            for a in (self._u, self._y, self._un, self._yn):
                a[:c] = a[c : 2 * c]
            self._n = n = c
        self._u[n], self._un[n] = u_row, un_row
        self._y[n] = y
        self._yn[n] = 2.0 * (y - self._y_low) / self._y_span - 1.0
        self._n = n + 1
        self._held += 1
        self._running = False

    def predict_one(self, u_next: ArrayLike | None = None) -> float:
        """``yhat(t+1)``, the next output one step ahead of the newest sample.

        ``u_next``, the input at the predicted instant, is needed only by a model with direct terms
        (an input at lag 0); any other model ignores it.

        Raises
        ------
        DataError
            If fewer than ``max_lag`` samples are held, or the model needs ``u_next`` and it is missing or bad.
        """
        n = self._n
        if min(self._held, n) < self._lag:
            self._needed()  # raises, saying how many samples are missing
        if u_next is not None:  # the slot after the newest sample: only a direct term (lag 0) reads it
            self._un[n] = 2.0 * (_inputs("u_next", u_next, self._model.n_inputs) - self._u_low) / self._u_span - 1.0
        elif self._direct:
            raise _u_next_missing(self._model)
        if self._median:  # a median ensemble: its members' median (in output units, as predict_osa's)
            return float(np.median([(net.yn(self._un, self._yn, n) + 1.0) * self._y_half + self._y_low
                                    for net in self._nets]))
        total = 0.0
        for net in self._nets:  # an ensemble's prediction is its members' mean (in output units, as predict_osa's)
            total += (net.yn(self._un, self._yn, n) + 1.0) * self._y_half + self._y_low
        return total / len(self._nets)

    def step(self, u: ArrayLike, interval: float | None = DEFAULT_LEVEL) -> Step:
        """The model run as a simulator, one instant a call: the next instant's :class:`~streamid.model.stepping.Step`
        (``y``, its band's ``lower`` and ``upper``, ``in_domain``) for ``u``, the input at that instant.

        The first call after measured samples (:meth:`learn_one`; or after :meth:`swap` or :meth:`reset`) starts a
        free run from the newest ``max_lag`` of them and gives ``yhat(t+1)`` for ``u = u(t+1)``; each further call
        gives the instant after, feeding back the run's own outputs only (never a measured one): ``k`` calls give
        what :meth:`forecast` gives for the plan of their inputs (a direct term, lag 0, reads ``u`` at its own
        instant; other models use it from the next instant on). A :meth:`learn_one` in between ends the run: the
        next call starts again from the measurements. ``interval``: a level of the model's interval (``lower`` and
        ``upper`` None when the model carries none, or with None). Each call costs the same bounded work
        (:mod:`~streamid.model.stepping`): about 12 us for a 10-neuron network with its band on a 2-core VM
        (``streamid bench --only engine``), the first after measurements about 2 us more per ``max_lag`` sample.

        Raises
        ------
        DataError
            If ``u`` is not finite or not one value per input, ``interval`` is not a level the model carries, or
            fewer than ``max_lag`` samples are held; the run is then unchanged.
        """
        m = self._model
        un: float | NDArray[np.float64]
        if self._scalar_u and isinstance(u, float) and isfinite(u):  # the common loop, as in learn_one
            u_row, un = np.array((u,)), 2.0 * (u - self._u_low0) / self._u_span0 - 1.0
        else:
            u_row = _inputs("u", u, m.n_inputs)
            un = 2.0 * (u_row - self._u_low) / self._u_span - 1.0
        q = band_quantile(m, interval)
        if not self._running:
            L = m.max_lag
            u_held, y_held = self._needed()
            n = self._n
            self._run.seed(u_held, y_held, self._un[n - L : n], self._yn[n - L : n])
            self._running = True
        return self._run.advance(u_row, un, q)

    @overload
    def forecast(self, u_plan: ArrayLike, interval: None = None) -> NDArray[np.float64]: ...

    @overload
    def forecast(self, u_plan: ArrayLike, interval: float) -> Band: ...

    def forecast(self, u_plan: ArrayLike, interval: float | None = None) -> NDArray[np.float64] | Band:
        """``yhat(t+1) .. yhat(t+H)``: the free run from the newest samples for the planned inputs.

        ``u_plan`` holds ``u(t+1) .. u(t+H)``, shape (H,) or (H, n_inputs).  The run feeds its own
        predictions back (it never sees a measured output after ``t``); with every input lag >= 1 the
        last planned input is not used. With ``interval`` (a level of the model's interval, e.g. 0.9) the
        forecast comes with its band's lower and upper paths (:class:`~streamid.model.uncertainty.Band`).

        Raises
        ------
        DataError
            If fewer than ``max_lag`` samples are held, or ``u_plan`` is not finite or of another shape.
        """
        m = self._model
        plan = _inputs("u_plan", u_plan, m.n_inputs, many=True)
        u, y = self._needed()
        L = m.max_lag
        if interval is not None:
            band = m.simulate(np.vstack([u, plan]), y, interval=interval)
            return Band(band.y[L:], band.lower[L:], band.upper[L:])
        return m.simulate(np.vstack([u, plan]), y)[L:]

    def in_domain(self, u_next: ArrayLike | None = None) -> bool:
        """Whether every regressor of the next prediction (from the newest samples, and ``u_next`` when given)
        lies inside the model's estimation domain (:func:`~streamid.model.domain.outside`): what an FMU's
        ``<output>_in_domain`` says at each step."""
        m = self._model
        k = min(self.held, m.max_lag)
        u, y = self._recent(k)
        nxt = _inputs("u_next", u_next, m.n_inputs)[None, :] if u_next is not None else np.zeros((1, m.n_inputs))
        regs = sorted({r for net in members_of(m) for r in (*net.regressors, *(net.linear_regressors or ()))},
                      key=lambda r: (r.signal, r.index, r.lag))
        if u_next is None:  # no input at the predicted instant: its direct terms (lag 0) are not judged
            regs = [r for r in regs if r.lag > 0]
        flags = outside(m.normalisation, regs, np.vstack([u, nxt]), np.concatenate([y, [m.normalisation.y_low]]))
        return not bool(flags[-1])

    def forecast_many(self, u_plans: ArrayLike) -> NDArray[np.float64]:
        """:meth:`forecast` for several candidate plans at once (what a model-predictive controller compares):
        ``u_plans`` of shape (P, H) or (P, H, n_inputs) gives (P, H), row ``p`` equal to ``forecast(u_plans[p])``.

        The free runs advance together (:meth:`Model.simulate_many <streamid.model.narx.Model.simulate_many>`):
        50 plans of 1 s take about a third of the time of 50 calls (3.2 ms against 9.1 ms on a 2-core VM,
        ``streamid bench --only engine``).

        Raises
        ------
        DataError
            If fewer than ``max_lag`` samples are held, or ``u_plans`` is not finite or of another shape.
        """
        m = self._model
        try:
            a = np.asarray(u_plans, dtype=np.float64)
        except (TypeError, ValueError):
            raise DataError(f"u_plans must be numbers; got {u_plans!r}") from None
        a = a[..., None] if a.ndim == 2 and m.n_inputs == 1 else a
        if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1 or a.shape[2] != m.n_inputs:
            form = "(P, H) or (P, H, 1)" if m.n_inputs == 1 else f"(P, H, {m.n_inputs})"
            raise DataError(f"u_plans must be an array of shape {form}, P >= 1 plans of H >= 1 samples; got shape "
                            f"{a.shape}")
        if not np.all(np.isfinite(a)):
            for k in range(a.shape[0]):
                check_finite(f"u_plans[{k}]", a[k])  # names the plan, then the sample
        u, y = self._needed()
        L = m.max_lag
        runs = m.simulate_many([(np.vstack([u, plan]), y) for plan in a])
        return np.stack([r[L:] for r in runs])

    def beyond_range(self, u_plan: ArrayLike | None = None) -> tuple[str, ...]:
        """Names of the signals that leave the model's estimation range by more than
        :data:`~streamid.model.domain.BEYOND_RANGE` of its span, in the samples a prediction uses now
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
        nets = members_of(model)
        big = max(nets, key=lambda m: m.neurons)
        if big.neurons > MAX_NEURONS or model.max_lag > MAX_LAG or model.n_inputs > MAX_INPUTS:
            raise DataError(f"a Predictor serves models of at most {MAX_NEURONS} neurons per network, lags up to "
                            f"{MAX_LAG} and {MAX_INPUTS} inputs; got {big.neurons} neurons, max_lag {model.max_lag}, "
                            f"{model.n_inputs} inputs")
        if current is not None and model.n_inputs != current.n_inputs:
            raise DataError(f"the new model takes {model.n_inputs} input(s) {model.input_names}, the served one "
                            f"{current.n_inputs} {current.input_names}: a Predictor's samples fit one input count")
        return model

    def _alloc(self, n_inputs: int) -> None:
        """Buffers of 2 _cap samples and one slot more (``u_next``'s), raw and in the served model's units."""
        rows = 2 * self._cap + 1
        self._u, self._y = np.zeros((rows, n_inputs)), np.zeros(rows)
        self._un, self._yn = np.zeros((rows, n_inputs)), np.zeros(rows)

    def _serve(self, model: Model) -> None:
        """Prepare ``model``'s networks and re-express the samples held in its normalisation."""
        norm: Normalisation = model.normalisation
        self._u_low, self._u_span = np.asarray(norm.u_low), np.asarray(norm.u_high) - np.asarray(norm.u_low)
        self._y_low, self._y_span, self._y_half = norm.y_low, norm.y_high - norm.y_low, norm.y_half_range
        self._un[: self._n], self._yn[: self._n] = norm.u(self._u[: self._n]), norm.y(self._y[: self._n])
        self._u_low0, self._u_span0 = float(self._u_low[0]), float(self._u_span[0])
        self._scalar_u = model.n_inputs == 1
        self._nets = [_Network(m) for m in members_of(model)]
        self._median = isinstance(model, EnsembleModel) and model.combine == "median"
        self._direct = has_direct_terms(model)
        self._run = FreeRun(model, self._nets)  # step()'s free run: its rings, seeded at the first step
        self._running = False
        self._lag = model.max_lag
        self._model = model

    def _recent(self, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self._u[self._n - k : self._n], self._y[self._n - k : self._n]

    def _needed(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        L = self._model.max_lag
        if self.held < L:
            raise DataError(f"this model needs the newest {L} samples (max_lag) before it predicts; "
                            f"{self.held} held since the start or the last reset")
        return self._recent(L)
