"""Identification of one closed window, off the receiving path.

:func:`identify_window` is a pure function of a :class:`~streamid.online.window.Window`
and the stream's settings: it splits the window (the newest
``validation_fraction`` is held out), runs the coevolution generation by
generation -- cold, or warm-started from the previous final populations, which
the engine re-evaluates on the new data -- checks the model on the validation
part, and returns an :class:`Outcome`.  The model is the run's best pair (lowest
one-step-ahead error, the paper's choice) or, with the engine setting
``selection = "fr_est"``, the one of the best pair and the final population
with the highest free-run R^2 on the estimation part (as
:func:`~streamid.engine.identify.identify` chooses; validation data are never
looked at).  It never raises for bad data or a
failed identification: those are outcomes (``dropped``, ``failed``,
``rejected``), counted by the service, which keeps the previous model.

It stops between two generations when ``stop`` is set (SIGINT/SIGTERM).
``on_generation(stream, progress)``, when given, is called after every
generation with the engine's :class:`~streamid.engine.coevolution.Progress`;
an exception it raises aborts that identification exactly as an engine error
would (the fault-injection tests use it to make real identifications fail).
"""

from __future__ import annotations

import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from streamid.daemon.config import StreamConfig
from streamid.online.summary import ValidationSummary, summarise
from streamid.online.window import Window
from streamid.engine import CoEAState, Coevolution, EvalHelper, Model
from streamid.engine.identify import free_run_r2
from streamid.errors import StreamidError

__all__ = ["Outcome", "Stopped", "identify_window", "signature_of", "rng_for"]


#: Smallest range (max - min) of a signal over a window part: the correlation tests use fourth powers of
#: the signals, which underflow float64 below about 1e-77; below this the window is dropped, not identified.
MIN_SPAN = 1e-60


class Stopped(Exception):
    """The daemon is stopping: the identification was abandoned between generations."""


@dataclass(frozen=True, eq=False)
class Outcome:
    """What became of one window.

    ``kind`` is ``"accepted"`` (a model to publish), ``"rejected"`` (a model
    that failed validation), ``"failed"`` (the identification raised) or
    ``"dropped"`` (the window could not be identified: constant signal, too
    short...).  ``reason`` says why for all but ``accepted``.
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

    @property
    def accepted(self) -> bool:
        return self.kind == "accepted"


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


def rng_for(cfg: StreamConfig, stream: str, version: int) -> np.random.Generator:
    """The generator of one update: seeded by (seed, stream, version), reproducible."""
    return np.random.default_rng([cfg.seed, zlib.crc32(stream.encode("utf-8")), int(version)])


def _pick_output(window: Window, cfg: StreamConfig) -> tuple[int, str] | str:
    names = window.output_names
    if cfg.output is None:
        return 0, names[0]
    if cfg.output not in names:
        return f"configured output {cfg.output!r} is not among the stream's outputs {list(names)}"
    return names.index(cfg.output), cfg.output


def identify_window(
    window: Window,
    cfg: StreamConfig,
    *,
    version: int,
    warm_state: CoEAState | None = None,
    warm_signature: dict[str, Any] | None = None,
    force_cold: bool = False,
    stop: threading.Event | None = None,
    on_generation: Callable[[str, Any], None] | None = None,
    helper: EvalHelper | None = None,
) -> Outcome:
    """Identify ``window``; ``version`` is the version the model would get.

    ``helper`` (an :class:`~streamid.engine.parallel.EvalHelper` this worker owns)
    evaluates half of every population batch; the outcome is the same without it.

    Raises
    ------
    Stopped
        If ``stop`` was set during the run.
    """
    t_start = time.perf_counter()
    picked = _pick_output(window, cfg)
    if isinstance(picked, str):
        return Outcome("dropped", picked, "output_missing")
    col, out_name = picked
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
    }
    common = {"window_meta": meta, "output_name": out_name, "input_names": window.input_names}
    max_lag = max(cfg.max_lag_y, cfg.max_lag_u)
    need_est = max_lag + 2 * cfg.neurons
    if n_est < need_est or n_val < max_lag + 3:
        return Outcome(
            "dropped",
            f"window too short for the configured lags: {n_est} estimation + {n_val} validation samples; "
            f"max lag {max_lag} and {cfg.neurons} neurons need >= {need_est} estimation and >= {max_lag + 3} "
            "validation samples (lengthen window_s or lower max_lag_y/max_lag_u/neurons)",
            "window_too_short",
            **common,
        )
    u_est, y_est, u_val, y_val = u[:n_est], y[:n_est], u[n_est:], y[n_est:]
    for name, part, a in [(f"input {s!r}", "estimation", u_est[:, i]) for i, s in enumerate(window.input_names)] + [
        (f"output {out_name!r}", "estimation", y_est), (f"output {out_name!r}", "validation", y_val)
    ]:
        span = float(a.max() - a.min())
        if not span > 0.0:
            why = f"{name} is constant over the {part} part ({a[0]:g}): zero range"
        elif not span >= MIN_SPAN:  # fourth powers (correlation tests) would underflow float64
            why = f"{name} spans only {span:.3g} over the {part} part, less than {MIN_SPAN:g}: too small for float64"
        else:
            continue
        return Outcome("dropped", f"{why}, no normalisation possible; waiting for a window with excitation",
                       "constant_signal", **common)
    sig = signature_of(window, cfg, out_name)
    warm = warm_state is not None and not force_cold and warm_signature == sig
    engine_cfg = cfg.coea_config(cold=not warm)
    rng = rng_for(cfg, window.stream, version)
    try:
        try:
            co = _start(u_est, y_est, engine_cfg, rng, warm_state if warm else None, window, out_name, meta, helper)
        except _WarmMismatch:  # the saved populations do not fit this data: start cold
            warm = False
            engine_cfg = cfg.coea_config(cold=True)
            co = _start(u_est, y_est, engine_cfg, rng, None, window, out_name, meta, helper)
    except StreamidError as exc:
        return Outcome("failed", f"identification could not start: {exc}", "engine_error", signature=sig, **common)
    try:
        for progress in co:
            if stop is not None and stop.is_set():
                raise Stopped
            if on_generation is not None:
                on_generation(window.stream, progress)
        model = co.best_model()
        if engine_cfg.selection == "fr_est":  # choose by free run on the estimation part, as identify() does
            cands = [model, *co.population_models()]
            scores = free_run_r2(cands, u_est, y_est)
            k = int(np.argmax(scores))
            model = cands[k].with_metrics(selection="fr_est", selection_score=float(scores[k]))
        state = co.state()
    except Stopped:
        raise
    except (StreamidError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return Outcome(
            "failed", f"identification failed: {type(exc).__name__}: {exc}", "engine_error", warm=warm, signature=sig, **common
        )
    fitness = np.asarray(co.history, dtype=np.float64)
    try:
        summary = summarise(model, u_est, y_est, u_val, y_val)
    except (StreamidError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return Outcome(
            "failed", f"validation failed to run: {type(exc).__name__}: {exc}", "engine_error", warm=warm, signature=sig, **common
        )
    seconds = time.perf_counter() - t_start
    m = summary.metrics
    reasons = []
    if not summary.finite:
        reasons.append("non-finite predictions or metrics")
    if not m.get("r2_osa_val", -np.inf) >= cfg.min_r2_osa:
        reasons.append(f"validation R² OSA {m.get('r2_osa_val', float('nan')):.4g} < min_r2_osa {cfg.min_r2_osa:g}")
    if not m.get("r2_fr_val", -np.inf) >= cfg.min_r2_fr:
        reasons.append(f"validation R² FR {m.get('r2_fr_val', float('nan')):.4g} < min_r2_fr {cfg.min_r2_fr:g}")
    kind = "rejected" if reasons else "accepted"
    if not reasons:
        model = model.with_metrics(**{k: v for k, v in m.items() if np.isfinite(v)})
    return Outcome(
        kind,
        "; ".join(reasons),
        "validation" if reasons else "",
        model=model,
        state=state,
        summary=summary,
        warm=warm,
        generations=engine_cfg.generations,
        fitness=fitness,
        seconds=seconds,
        signature=sig,
        u_val=u_val,
        y_val=y_val,
        **common,
    )


class _WarmMismatch(Exception):
    pass


def _start(
    u: np.ndarray,
    y: np.ndarray,
    engine_cfg: Any,
    rng: np.random.Generator,
    warm: CoEAState | None,
    window: Window,
    out_name: str,
    meta: dict[str, Any],
    helper: EvalHelper | None = None,
) -> Coevolution:
    try:
        return Coevolution(
            u, y, engine_cfg, rng, warm_start=warm, input_names=window.input_names, output_name=out_name,
            window={"stream": window.stream, **meta}, helper=helper,
        )
    except StreamidError:
        if warm is not None:
            raise _WarmMismatch from None
        raise
