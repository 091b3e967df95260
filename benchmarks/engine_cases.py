"""Engine benchmark cases behind ``streamid bench`` (section ``engine``).

Each ``*_case(seed)`` runs one identification on the project's own data (the
reactor simulator; the MR damper and piezo logs bundled in ``streamid/data``)
and returns a dict of figures; :func:`bench` turns repeated cases into the
table rows of :mod:`benchmarks.kit`.

Figures and targets (issue 2)
------------------------------
* reactor (paper eq. 17, 480 + 480 samples, G=400, M=10, L=10): whole
  identification time (8,040 evaluations), FR validation R^2 (>= 0.9999), lags
  ``y(t-1), u(t-1), u(t-2)`` (optionally ``y(t-2)``);
* MR damper (first 2000 estimation, last 1499 validation): the paper's settings
  (G=200, M=10) and streamid's defaults (:data:`~streamid.engine.settings.DEFAULT`,
  <= 3 s wall, OSA val R^2 >= 0.996, FR val R^2 median >= 0.98, min >= 0.97);
* piezo (first half / second half, M=13, G=100): FR val R^2 >= 0.9997;
* scaling: seconds of one run for N = 480, 2000, 10000 and M = 10, 20, 40;
* a controller's loop (:class:`~streamid.model.predictor.Predictor`, an MR damper model of the paper's size):
  microseconds per sample of ``learn_one`` + ``predict_one``, and per 1 s (200-sample) ``forecast``.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from functools import lru_cache
from typing import Any

import numpy as np

from streamid.engine.settings import DEFAULT, PAPER, CoEAConfig
from streamid.engine.identification import identify
from streamid.engine.search.parallel import EvalHelper
from streamid.engine.validation import prediction_r2

__all__ = [
    "reactor_case",
    "mr_damper_case",
    "mr_damper_paper_case",
    "piezo_case",
    "scaling_case",
    "predictor_case",
    "reactor_lags_ok",
    "bench",
]

REACTOR_CONFIG = PAPER.replace(neurons=10, generations=400, max_lag_y=10, max_lag_u=10)
MR_PAPER_CONFIG = PAPER.replace(neurons=10, generations=200)
PIEZO_CONFIG = PAPER.replace(neurons=13, generations=100)


@lru_cache(maxsize=4)
def _log(name: str, inp: str, out: str) -> tuple[np.ndarray, np.ndarray]:
    from streamid.logs import bundled_log, read_log_arrays

    arr = read_log_arrays(bundled_log(name))
    return np.asarray(arr.inputs[inp], dtype=np.float64), np.asarray(arr.outputs[out], dtype=np.float64)


def mr_damper_data() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u_est, y_est, u_val, y_val): the bundled MR damper log, 2000 + 1499 samples."""
    u, y = _log("mr_damper", "velocity_cm_s", "force_N")
    return u[:2000], y[:2000], u[2000:], y[2000:]


def piezo_data() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u_est, y_est, u_val, y_val): the bundled piezo log, first half / second half."""
    u, y = _log("piezo_p885", "voltage_V", "displacement_um")
    k = len(y) // 2
    return u[:k], y[:k], u[k:], y[k:]


def reactor_data(seed: int, n_est: int = 480, n_val: int = 480) -> tuple[np.ndarray, ...]:
    """(u_est, y_est, u_val, y_val) from the reactor simulator (the seed draws the input)."""
    from streamid.sim import simulate_reactor

    _, u, y = simulate_reactor(n_est + n_val, seed)
    return u[:n_est], y[:n_est], u[n_est:], y[n_est:]


def reactor_lags_ok(lags: dict[str, Any]) -> bool:
    """Exactly ``y(t-1), u(t-1), u(t-2)``, optionally with ``y(t-2)``."""
    return lags["u"] == [[1, 2]] and lags["y"] in ([1], [1, 2])


def _case(cfg: CoEAConfig, seed: int, data: tuple[np.ndarray, ...], **kw: Any) -> dict[str, Any]:
    """One identification (``kw`` to :func:`identify`) timed, validated on the held-out data."""
    ue, ye, uv, yv = data
    t0 = time.perf_counter()
    res = identify(ue, ye, cfg, seed, **kw)
    seconds = time.perf_counter() - t0
    osa_v, fr_v, _ = prediction_r2(res.model, uv, yv)
    osa_e, fr_e, _ = prediction_r2(res.model, ue, ye)
    return {
        "seed": seed,
        "seconds": seconds,
        "evaluations": res.evaluations,
        "fitness": res.fitness,
        "osa_est": osa_e,
        "fr_est": fr_e,
        "osa_val": osa_v,
        "fr_val": fr_v,
        "lags": res.model.lags,
    }


def reactor_case(seed: int, helper: EvalHelper | None = None) -> dict[str, Any]:
    """The paper's reactor identification (one run, G=400, M=10, L=10) on simulated 480 + 480 samples.

    With ``helper`` (a started :class:`~streamid.engine.search.parallel.EvalHelper`) the run uses both cores.
    """
    out = _case(REACTOR_CONFIG, seed, reactor_data(seed), helper=helper)
    out["lags_ok"] = reactor_lags_ok(out["lags"])
    return out


def mr_damper_case(seed: int, config: CoEAConfig | None = None) -> dict[str, Any]:
    """streamid's default identification of the real MR damper (wall time includes the worker processes)."""
    return _case(DEFAULT if config is None else config, seed, mr_damper_data())


def mr_damper_paper_case(seed: int, helper: EvalHelper | None = None) -> dict[str, Any]:
    """The paper's settings (one run, G=200, M=10) on the real MR damper."""
    return _case(MR_PAPER_CONFIG, seed, mr_damper_data(), helper=helper)


def piezo_case(seed: int, helper: EvalHelper | None = None) -> dict[str, Any]:
    """The paper's settings (one run, G=100, M=13) on the real piezo actuator log."""
    return _case(PIEZO_CONFIG, seed, piezo_data(), helper=helper)


def scaling_case(
    n_est: int, neurons: int, seed: int = 0, generations: int = 100, helper: EvalHelper | None = None
) -> dict[str, Any]:
    """Seconds of one paper-style run (P=20, L=10) on ``n_est`` reactor samples with ``neurons`` neurons."""
    cfg = PAPER.replace(neurons=neurons, generations=generations)
    ue, ye, _, _ = reactor_data(seed, n_est, 10)
    t0 = time.perf_counter()
    res = identify(ue, ye, cfg, seed, helper=helper)
    seconds = time.perf_counter() - t0
    return {
        "n_est": n_est,
        "neurons": neurons,
        "generations": generations,
        "seconds": seconds,
        "evaluations": res.evaluations,
        "us_per_evaluation": 1e6 * seconds / res.evaluations,
    }


def predictor_case(seed: int) -> dict[str, Any]:
    """A controller's loop on the bundled MR damper: a model of the paper's size (M=10, G=50) identified on
    the first 2,000 samples, then every sample of the log through ``learn_one`` and ``predict_one``, a
    ``forecast`` of 200 samples (1 s) from each of 50 points, ``forecast_many`` of 50 plans from 10 of
    them, and the model run as a simulator (``step`` with its 90 % band, when it carries one, and domain flag)
    over the log from its first ``max_lag`` samples (medians)."""
    from streamid.model.predictor import Predictor

    u, y, _, _ = mr_damper_data()
    model = identify(u, y, MR_PAPER_CONFIG.replace(generations=50), np.random.default_rng(seed)).model
    ua, ya = _log("mr_damper", "velocity_cm_s", "force_N")
    p = Predictor(model)
    step: list[float] = []
    for k in range(ua.shape[0]):
        t0 = time.perf_counter()
        p.learn_one(ua[k], ya[k])
        if p.ready:
            p.predict_one()
        step.append(time.perf_counter() - t0)
    sim = Predictor(model)
    for k in range(model.max_lag):
        sim.learn_one(ua[k], ya[k])
    stepped: list[float] = []
    for k in range(model.max_lag, ua.shape[0]):
        uk = float(ua[k])
        t0 = time.perf_counter()
        sim.step(uk)
        stepped.append(time.perf_counter() - t0)
    q = Predictor(model)
    plans: list[float] = []
    many: list[float] = []  # 50 candidate plans of 1 s at once: the planned inputs scaled by 0.5..1.5
    gains = np.linspace(0.5, 1.5, 50)[:, None]
    for k in range(ua.shape[0] - 200):
        q.learn_one(ua[k], ya[k])
        if q.ready and k % 60 == 0 and len(plans) < 50:
            t0 = time.perf_counter()
            q.forecast(ua[k + 1 : k + 201])
            plans.append(time.perf_counter() - t0)
            if len(many) < 10:
                t0 = time.perf_counter()
                q.forecast_many(gains * ua[None, k + 1 : k + 201])
                many.append(time.perf_counter() - t0)
    return {"us_per_sample": 1e6 * float(np.median(step)), "us_per_forecast_1s": 1e6 * float(np.median(plans)),
            "ms_per_50_forecasts_1s": 1e3 * float(np.median(many)), "us_per_step": 1e6 * float(np.median(stepped)),
            "max_lag": model.max_lag, "band": model.interval is not None}


def _rows(section: str, case: str, results: list[dict[str, Any]], metrics: Iterable[tuple[str, str, str]]) -> Iterator[Any]:
    from benchmarks.kit import Measurement

    for key, unit, note in metrics:
        yield Measurement(section, case, key, unit, tuple(float(r[key]) for r in results), note)


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench`` provider: the engine's figures (medians over ``options.repeat`` seeds).

    One-run cases are measured twice where it matters: in one process (one core)
    and with an :class:`~streamid.engine.search.parallel.EvalHelper` started beforehand
    (both cores; a daemon or ``streamid identify`` keeps one for all its runs).
    """
    helper = EvalHelper() if EvalHelper.supported() else None
    try:
        yield from _bench(options, helper)
    finally:
        if helper is not None:
            helper.close()


def _bench(options: Any, helper: EvalHelper | None) -> Iterator[Any]:
    from benchmarks.kit import Measurement

    # --quick is a smoke run (every row and the code behind it, no figure to quote): one seed, as the other sections
    n = 1 if options.quick else max(1, options.repeat)
    seeds = [options.seed + i for i in range(n)]
    variants = [("one core", None)] + ([("two cores, helper", helper)] if helper is not None else [])
    for label, h in variants:
        rea = [reactor_case(s, h) for s in seeds]
        case = f"reactor G=400 M=10 (paper), {label}"
        yield from _rows(
            "engine",
            case,
            rea,
            [
                ("seconds", "s", "whole identification, 8,040 evaluations; target <= 0.10 median"),
                ("fr_val", "R2", "free run, validation; target >= 0.9999 each"),
                ("osa_val", "R2", "one step ahead, validation"),
            ],
        )
        yield Measurement(
            "engine", case, "lags y1,u1,u2(,y2)", "fraction",
            (float(np.mean([r["lags_ok"] for r in rea])),), "target >= 0.8",
        )
    mrp = [mr_damper_paper_case(s, helper) for s in seeds]
    yield from _rows(
        "engine", "MR damper, paper G=200 M=10", mrp,
        [("fr_val", "R2", "free run, validation (paper's best of 30: 0.9591)"), ("osa_val", "R2", ""),
         ("seconds", "s", "one run, two cores (helper)" if helper is not None else "one run")],
    )
    mrd = [mr_damper_case(s) for s in seeds]
    yield from _rows(
        "engine", "MR damper, streamid defaults", mrd,
        [
            ("fr_val", "R2", "target median >= 0.98, min >= 0.97"),
            ("osa_val", "R2", "target >= 0.996 each"),
            ("seconds", "s", f"wall, {DEFAULT.restarts} runs in one process; target <= 3"),
        ],
    )
    pz = [piezo_case(s, helper) for s in seeds]
    yield from _rows(
        "engine", "piezo G=100 M=13 (paper)", pz,
        [("fr_val", "R2", "target >= 0.9997 each"), ("osa_val", "R2", ""),
         ("seconds", "s", "one run, two cores (helper)" if helper is not None else "one run")],
    )
    pr = [predictor_case(s) for s in seeds]
    yield from _rows(
        "engine", "controller loop: Predictor on the MR damper (M=10)", pr,
        [("us_per_sample", "us", "learn_one + predict_one, median over the log's 3,499 samples"),
         ("us_per_forecast_1s", "us", "forecast of 200 samples (1 s) from the newest samples, median of 50"),
         ("ms_per_50_forecasts_1s", "ms", "forecast_many: 50 candidate plans of 1 s at once, median of 10"),
         ("us_per_step", "us", "step: the model as a simulator, its 90 % band and domain flag, median over the log"
          + ("" if all(r["band"] for r in pr) else " (a model without interval: no band)"))],
    )
    sizes = (480, 2000) if options.quick else (480, 2000, 10000)
    for n_est in sizes:
        for m in (10, 20, 40):
            reps = [scaling_case(n_est, m, s, generations=20 if options.quick else 100, helper=helper)
                    for s in seeds[: max(1, min(3, n))]]
            yield from _rows(
                "engine", f"scaling N={n_est} M={m}", reps,
                [("seconds", "s", f"one run, G={reps[0]['generations']}, P=20"
                  + (", two cores (helper)" if helper is not None else "")), ("us_per_evaluation", "us", "")],
            )
