"""One online update as a pure computation: an :class:`UpdateJob` in, an :class:`Outcome` out.

:meth:`OnlineIdentifier.next_job <streamid.online.OnlineIdentifier.next_job>`
takes the oldest pending window and everything the run depends on (the
settings, the version the model would get, the warm-start populations, whether
to start cold) into a frozen :class:`UpdateJob`.  :meth:`UpdateJob.run` touches
no identifier state, so a caller runs it on any thread (the daemon's workers)
while samples keep arriving; :meth:`OnlineIdentifier.finish
<streamid.online.OnlineIdentifier.finish>` then decides acceptance and numbers
the version.

A run splits the window (the newest ``validation_fraction`` is held out), runs
the coevolution generation by generation on at most a bounded, stratified set of
the estimation rows (:mod:`streamid.online.rows`: 4,096 with the defaults, so an
update's cost is set by the model's size, not the stream's sample rate) -- cold,
or warm-started from the previous final populations, which the engine re-evaluates
on the new data --
chooses the model with the engine's one selection rule
(:func:`~streamid.engine.identification.select_model`: ``"fitness"``, the paper's,
or ``"fr_est"``; validation data are never looked at), lets a dense linear ARX
part longer than the lag search's compete with it (:func:`long_linear_part`),
and computes its validation figures (:mod:`streamid.online.summary`).  It never raises for bad
data or a failed identification: those are outcomes (``dropped``,
``failed``).  It stops between two generations when ``stop`` is set, raising
:class:`Stopped`.  ``on_generation(stream, progress)``, when given, is called
after every generation; an exception it raises fails that run like an engine
error (the fault-injection tests use it).
"""

from __future__ import annotations

import dataclasses
import math
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from streamid.engine import CoEAState, Coevolution, EvalHelper
from streamid.model import Model
from streamid.model.domain import outside_share
from streamid.model.uncertainty import interval_report
from streamid.engine.fit.blas import one_blas_thread
from streamid.engine.choice.scores import RANGE_MARGIN
from streamid.engine.search.feedthrough import direct_terms
from streamid.engine.identification import select_model
from streamid.engine.choice.longlinear import long_linear_choice
from streamid.engine.choice.calibration import with_interval
from streamid.engine.choice.refine import ABOVE as REFINE_ABOVE, refine_judged
from streamid.engine.settings import MORE_BELOW, RIDGE, CoEAConfig
from streamid.errors import StreamidError
from streamid.online.recalibrate import recalibrate
from streamid.engine.search.rows import RowSample, informative_rows, search_row_bound
from streamid.online.stream_config import StreamConfig
from streamid.online.summary import ValidationSummary, r2_or_nan, summarise
from streamid.online.window_types import Window

__all__ = ["Outcome", "Stopped", "UpdateJob", "identify_window", "long_linear_part", "signature_of", "rng_for",
           "MIN_SPAN"]


#: Smallest range (max - min) of a signal over a window part: the correlation tests use fourth powers of
#: the signals, which underflow float64 below about 1e-77; below this the window is dropped, not identified.
MIN_SPAN = 1e-60

_ENGINE_ERRORS = (StreamidError, ArithmeticError, ValueError, np.linalg.LinAlgError)


class Stopped(Exception):
    """The caller asked to stop: the identification was abandoned between generations."""


class StopFlag(Protocol):
    """What :meth:`UpdateJob.run` polls between generations (e.g. a ``threading.Event``)."""

    def is_set(self) -> bool: ...


@dataclass(frozen=True, eq=False)
class Outcome:
    """What one run made of a window.

    ``kind`` is ``"identified"`` (a candidate model with its validation figures,
    to be judged by :meth:`~streamid.online.OnlineIdentifier.finish`),
    ``"failed"`` (the identification raised) or ``"dropped"`` (the window could
    not be identified: constant signal, too short...).  ``reason`` says why for
    the last two, ``code`` is a short machine-readable form of it.
    """

    kind: str
    reason: str = ""
    code: str = ""
    model: Model | None = None
    state: CoEAState | None = None
    summary: ValidationSummary | None = None
    window_meta: dict[str, Any] = field(default_factory=dict)
    warm: bool = False
    generations: int = 0
    fitness: np.ndarray = field(default_factory=lambda: np.empty(0))
    seconds: float = 0.0
    signature: dict[str, Any] = field(default_factory=dict)
    output_name: str = ""
    input_names: tuple[str, ...] = ()
    u_val: np.ndarray = field(default_factory=lambda: np.empty((0, 1)))
    y_val: np.ndarray = field(default_factory=lambda: np.empty(0))
    champion_metrics: dict[str, float] | None = None  # the champion on the same held-out data (None: none/can't run)
    champion_fr_val: np.ndarray = field(default_factory=lambda: np.empty(0))
    t_val_ns: int = 0  # stream time of the first held-out sample


def signature_of(window: Window, cfg: StreamConfig, output: str) -> dict[str, Any]:
    """What a warm start depends on: if any of it differs, the run starts cold."""
    return {
        "inputs": list(window.input_names),
        "output": output,
        "period_ns": int(window.period_ns),
        "neurons": cfg.neurons,
        "max_lag_y": cfg.max_lag_y,
        "max_lag_u": cfg.max_lag_u,
        "population": cfg.population,
    }


def rng_for(cfg: StreamConfig, stream: str, version: int, output_index: int = 0) -> np.random.Generator:
    """The generator of one update: seeded by (seed, stream, version[, output index]), reproducible."""
    key = [cfg.seed, zlib.crc32(stream.encode("utf-8")), int(version)] + ([output_index] if output_index else [])
    return np.random.default_rng(key)


@dataclass(frozen=True, eq=False)
class UpdateJob:
    """Everything one update needs, frozen when it was taken from the identifier.

    Attributes
    ----------
    window
        The closed window to identify.
    config
        The stream's settings.
    version
        The version the model gets if it is accepted (also seeds the run).
    warm_state, warm_signature
        The previous run's final populations and what they were fitted to.
    force_cold
        Start cold whatever the populations (after repeated failures).
    output
        The output to model (None: ``config.output``, or the first).
    champion
        The model served for that output now: evaluated on the same held-out data.
    generations
        Generations of this run when it is escalated after a drift (None: the cold/warm setting).
    cut_t_ns
        Identify only the samples from this stream time on (after a drift: the data before the change
        would teach the old dynamics); None: the whole window.
    shortened_first
        ``generations`` is a stream's shortened first run (others wait for theirs), not an escalation.
    """

    window: Window
    config: StreamConfig
    version: int
    warm_state: CoEAState | None = None
    warm_signature: dict[str, Any] | None = None
    force_cold: bool = False
    output: str | None = None
    champion: Model | None = None
    generations: int | None = None
    cut_t_ns: int | None = None
    shortened_first: bool = False

    def run(
        self,
        *,
        stop: StopFlag | None = None,
        on_generation: Callable[[str, Any], None] | None = None,
        helper: EvalHelper | None = None,
    ) -> Outcome:
        """Identify the window; pure computation (see the module docstring).

        ``helper`` (an :class:`~streamid.engine.search.parallel.EvalHelper` the caller
        owns) evaluates half of every population batch; the outcome is the same
        without it.

        Raises
        ------
        Stopped
            If ``stop`` was set during the run.
        """
        return identify_window(
            self.window, self.config, version=self.version, warm_state=self.warm_state,
            warm_signature=self.warm_signature, force_cold=self.force_cold, stop=stop,
            on_generation=on_generation, helper=helper, output=self.output, champion=self.champion,
            generations=self.generations, cut_t_ns=self.cut_t_ns,
        )


def _pick_output(window: Window, cfg: StreamConfig, output: str | None = None) -> tuple[int, str] | str:
    names = window.output_names
    want = output if output is not None else cfg.output
    if want is None:
        return 0, names[0]
    if want not in names:
        return f"configured output {want!r} is not among the stream's outputs {list(names)}"
    return names.index(want), want


def cut_window(window: Window, t_ns: int) -> Window:
    """The part of ``window`` from stream time ``t_ns`` on (the whole window if it starts later)."""
    k = -(-(int(t_ns) - window.t0_ns) // window.period_ns)
    if k <= 0:
        return window
    k = min(k, window.n)
    return dataclasses.replace(window, u=window.u[k:], y=window.y[k:], t0_ns=window.t0_ns + k * window.period_ns)


def champion_figures(champion: Model | None, u_val: np.ndarray, y_val: np.ndarray) -> tuple[dict[str, float] | None, np.ndarray]:
    """The champion's OSA and free-run R^2 and OSA mean-square error on held-out data, and its free run there."""
    if champion is None or u_val.shape[1] != champion.n_inputs or y_val.size <= champion.max_lag + 2:
        return None, np.empty(0)
    L = champion.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        osa = champion.predict_osa(u_val, y_val)
        fr = champion.simulate(u_val, y_val[:L])
    e = y_val[L:] - osa[L:]
    figs = {"r2_osa_val": r2_or_nan(y_val[L:], osa[L:]), "r2_fr_val": r2_or_nan(y_val[L:], fr[L:]),
            "mse_osa_val": float(np.mean(e * e)) if np.isfinite(e).all() else float("nan"),
            "outside_domain_val": outside_share(champion, u_val, y_val)}
    band = interval_report(champion, u_val, y_val, free_run=fr)  # the champion's interval on current data
    if band is not None:
        figs["interval_coverage_val"] = band["coverage"]
    return figs, np.asarray(fr, dtype=np.float64)


def _unusable(names_parts: list[tuple[str, str, np.ndarray]]) -> str | None:
    """Why a part of the window cannot be normalised (None: every signal has a usable range)."""
    for name, part, a in names_parts:
        span = float(a.max() - a.min())
        if not span > 0.0:
            why = f"{name} is constant over the {part} part ({a[0]:g}): zero range"
        elif not span >= MIN_SPAN:  # fourth powers (correlation tests) would underflow float64
            why = f"{name} spans only {span:.3g} over the {part} part, less than {MIN_SPAN:g}: too small for float64"
        else:
            continue
        return f"{why}, no normalisation possible; waiting for a window with excitation"
    return None


def _shortest_window(need_est: int, need_val: int, validation_fraction: float) -> int:
    """Fewest samples a window needs for ``need_est`` estimation and ``need_val`` validation samples, split as
    :func:`identify_window` splits (``round(n * validation_fraction)`` held out)."""
    f = min(max(validation_fraction, 1e-9), 1 - 1e-9)
    n = max(need_est + need_val, math.ceil((need_val - 0.5) / f) - 1, math.ceil((need_est - 0.5) / (1 - f)) - 1)
    for _ in range(10_000):  # from a lower bound: the split rounds, so a few more samples at most
        n_val = int(round(n * validation_fraction))
        if n - n_val >= need_est and n_val >= need_val:
            return n
        n += 1
    return n


def identify_window(
    window: Window,
    cfg: StreamConfig,
    *,
    version: int,
    warm_state: CoEAState | None = None,
    warm_signature: dict[str, Any] | None = None,
    force_cold: bool = False,
    stop: StopFlag | None = None,
    on_generation: Callable[[str, Any], None] | None = None,
    helper: EvalHelper | None = None,
    output: str | None = None,
    champion: Model | None = None,
    generations: int | None = None,
    cut_t_ns: int | None = None,
) -> Outcome:
    """Identify ``window`` (the body of :meth:`UpdateJob.run`); ``version`` is the version the model would get.

    The search sees at most :func:`~streamid.online.rows.search_row_bound` rows of the estimation part (one per
    stratum, :mod:`streamid.online.rows`; the model's ``metrics.search_rows`` says how many of how many); the
    chosen model is refitted on every row and validated on the whole held-out part, the validation with one BLAS
    thread (the correlation tests' products took 0.3 s instead of 1 ms with two threads on a busy machine; the
    engine's own passes limit it themselves).
    """
    t_start = time.perf_counter()
    picked = _pick_output(window, cfg, output)
    if isinstance(picked, str):
        return Outcome("dropped", picked, "output_missing")
    col, out_name = picked
    if cut_t_ns is not None:
        window = cut_window(window, cut_t_ns)
    u = window.u
    y = np.ascontiguousarray(window.y[:, col])
    n = window.n
    n_val = int(round(n * cfg.validation_fraction))
    n_est = n - n_val
    meta = {
        "number": window.number,
        "t0_ns": int(window.t0_ns),
        "t_end_ns": int(window.t_end_ns),
        "period_ns": int(window.period_ns),
        "n_samples": n,
        "n_estimation": n_est,
        "n_validation": n_val,
        "coalesced_before": int(window.coalesced_before),
        "output": out_name,
    }
    common: dict[str, Any] = {"window_meta": meta, "output_name": out_name, "input_names": window.input_names}
    max_lag = max(cfg.max_lag_y, cfg.max_lag_u)
    need_est = max_lag + 2 * cfg.neurons
    if n_est < need_est or n_val < max_lag + 3:
        n_min = _shortest_window(need_est, max_lag + 3, cfg.validation_fraction)
        period_s = window.period_ns / 1e9
        return Outcome(
            "dropped",
            f"window too short for the configured lags: {n_est} estimation + {n_val} validation samples; "
            f"max lag {max_lag} and {cfg.neurons} neurons need >= {need_est} estimation and >= {max_lag + 3} "
            f"validation samples (lengthen window_s or lower max_lag_y/max_lag_u/neurons: at this stream's "
            f"{period_s:g} s per sample, window_s >= {n_min * period_s:g} or window_samples >= {n_min})",
            "window_too_short",
            **common,
        )
    u_est, y_est, u_val, y_val = u[:n_est], y[:n_est], u[n_est:], y[n_est:]
    why = _unusable(
        [(f"input {s!r}", "estimation", u_est[:, i]) for i, s in enumerate(window.input_names)]
        + [(f"output {out_name!r}", "estimation", y_est), (f"output {out_name!r}", "validation", y_val)]
    )
    if why is not None:
        return Outcome("dropped", why, "constant_signal", **common)
    sig = signature_of(window, cfg, out_name)
    warm = warm_state is not None and not force_cold and warm_signature == sig
    engine_cfg, _ = direct_terms(cfg.coea_config(cold=not warm, generations=generations), u_est, y_est,
                                 warm_state if warm else None)  # u(t) a candidate? (engine.direct_terms)
    rng = rng_for(cfg, window.stream, version, col)
    bound = search_row_bound(cfg.neurons, cfg.max_lag_y, cfg.max_lag_u, u_est.shape[1], dict(cfg.engine))
    sample = informative_rows(n_est - engine_cfg.max_lag, bound, rng.spawn(1)[0])  # its own stream: the search's is kept
    try:
        try:
            co = _start(u_est, y_est, engine_cfg, rng, warm_state if warm else None, window,
                        out_name, meta, helper, sample)
        except _WarmMismatch:  # the saved populations do not fit this data: start cold
            warm = False
            engine_cfg, _ = direct_terms(cfg.coea_config(cold=True, generations=generations), u_est, y_est, None)
            co = _start(u_est, y_est, engine_cfg, rng, None, window, out_name, meta, helper, sample)
    except StreamidError as exc:
        return Outcome("failed", f"identification could not start: {exc}", "engine_error", signature=sig, **common)
    try:
        for progress in co:
            if stop is not None and stop.is_set():
                raise Stopped
            if on_generation is not None:
                on_generation(window.stream, progress)
        # with a sample of rows the candidates are screened on it and only the chosen one refitted on every row:
        # fitting all of them on every row would cost what the sample saved
        model, score = select_model(co, u_est, y_est, engine_cfg.selection, screen_rows=sample is not None)
        state, fitness = co.state(), np.asarray(co.history, dtype=np.float64)
        del co  # the run's tables (the search's, any lag matrix) are not needed past the choice: freed before refining
        model, score = long_linear_part(model, score, engine_cfg, u_est, y_est)
        if engine_cfg.selection != "fitness":
            model = model.with_metrics(selection=engine_cfg.selection, selection_score=score)
        if sample is not None:
            model = model.with_metrics(search_rows=sample.evidence())
        if engine_cfg.refine_iterations:  # the weights fitted to the free run, judged out of sample (ONLINE_REFINE)
            model, refined = refine_judged(model, u_est, y_est, engine_cfg.refine_iterations, REFINE_ABOVE,
                                           RANGE_MARGIN)
            model = model.with_metrics(refinement=refined)
        model = with_interval(model, u_est, y_est, RIDGE)  # its free-run interval, calibrated on a held-out half
        with one_blas_thread():  # the validation's products: steady with one thread (see identify_window)
            summary = summarise(model, u_est, y_est, u_val, y_val)
            if generations is not None and champion is not None and champion.n_inputs == u_est.shape[1]:
                # after a drift (an escalated run): the champion rescaled to the new output level competes too
                recal = recalibrate(champion, u_est, y_est)
                alt = None if recal is None else summarise(recal, u_est, y_est, u_val, y_val)
                if alt is not None and recal is not None and alt.finite and not (
                        alt.metrics["r2_fr_val"] <= summary.metrics["r2_fr_val"]):
                    model, summary = recal, alt
            champ, champ_fr = champion_figures(champion, u_val, y_val)
    except Stopped:
        raise
    except _ENGINE_ERRORS as exc:
        return Outcome(
            "failed", f"identification failed: {type(exc).__name__}: {exc}", "engine_error", warm=warm, signature=sig,
            **common,
        )
    return Outcome(
        "identified",
        model=model,
        state=state,
        summary=summary,
        warm=warm,
        generations=engine_cfg.generations,
        fitness=fitness,
        seconds=time.perf_counter() - t_start,
        signature=sig,
        u_val=u_val,
        y_val=y_val,
        champion_metrics=champ,
        champion_fr_val=champ_fr,
        t_val_ns=int(window.t0_ns + n_est * window.period_ns),
        **common,
    )


#: The largest design (rows x columns x 8 bytes) of an online update's long linear part: its QR is most of its cost,
#: and it bounds that cost on a long window. The F-16's 10 s windows (2,800 estimation rows) are bound by their rows
#: (order 134, a 6 MB design); a 20 kHz piezo window (7,000 rows) offers orders up to 64 (with the offline 256 MiB: 256, and
#: 1.4-1.9 s of the 0.5 s its decisions have, measured on this 2-core VM; with this bound 0.1-0.2 s).
LONG_LINEAR_DESIGN_BYTES = 8 * 2**20


def long_linear_part(model: Model, score: float, cfg: CoEAConfig, u: np.ndarray, y: np.ndarray) -> tuple[Model, float]:
    """The run's model, or the same network with a dense linear ARX part longer than the lag search's, and its score.

    ``engine.long_linear`` (:data:`~streamid.online.stream_config.ONLINE_LONG_LINEAR` online) > 0 and
    ``"fr_est"``: the rule of :mod:`streamid.engine.choice.longlinear` on the window's estimation part, tried when
    the network's free run explains less than ``more_below`` (0.95) of it, offering only orders above the lag
    search's largest lag (``max(max_lag_y, max_lag_u)``, 10 online), with a design of at most
    :data:`LONG_LINEAR_DESIGN_BYTES`. Why only those orders: the online lag search
    stops at lag 10 so that updates keep up (the 20 kHz piezo's decisions within 0.5 s), and a lightly damped
    structure sampled fast needs a memory of 100 samples or more (the F-16: modes of a few Hz at 400 Hz); a
    shorter linear part adds no memory the lag search could not have found, and when it was offered too the
    simulated MR damper's champions took orders 2-8 in 14 of 36 updates and its drift detection slowed (29 of 32
    changes within 3 s against 32; docs/benchmarks.md). ``score`` is the chosen model's estimation free-run R^2.
    """
    if not cfg.long_linear or cfg.selection != "fr_est" or not score < MORE_BELOW:
        return model, score
    ll, ev = long_linear_choice(model, score, cfg.long_linear, u, y, RANGE_MARGIN, RIDGE,
                                min_order=max(cfg.max_lag_y, cfg.max_lag_u) + 1, max_design_bytes=LONG_LINEAR_DESIGN_BYTES)
    if ll is None:
        return model, score
    taken = float(ev["r2_fr_est"])
    brief = {"order": int(ev["order"]), "r2_fr_est": taken, "r2_fr_est_without": float(score),
             "criterion": float(ev["criterion"]), "criterion_without": ev["criterion_without"]}
    return ll.with_metrics(long_linear=brief), taken


class _WarmMismatch(Exception):
    pass


def _start(
    u: np.ndarray,
    y: np.ndarray,
    engine_cfg: CoEAConfig,
    rng: np.random.Generator,
    warm: CoEAState | None,
    window: Window,
    out_name: str,
    meta: dict[str, Any],
    helper: EvalHelper | None = None,
    sample: RowSample | None = None,
) -> Coevolution:
    try:
        return Coevolution(
            u, y, engine_cfg, rng, warm_start=warm, input_names=window.input_names, output_name=out_name,
            window={"stream": window.stream, **meta}, helper=helper, rows=None if sample is None else sample.rows,
        )
    except StreamidError:
        if warm is not None:
            raise _WarmMismatch from None
        raise
