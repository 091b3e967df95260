"""How the restarts of one identification spread on the next experiment (issue 37, round 3).

For each target of the two-experiment suite and each seed: every restart's own model (``Result.extra["run_models"]``,
before the final choice, long linear part, means and refinement) scored on the validation experiment beside its
estimation free-run R² (the score the final choice ranks it by), the kept model's validation R², and the median and
the mean of the admissible runs' free runs (each run on its own past outputs, combined per sample)::

    python -m benchmarks.run_spread piezo_sim,bouc_wen_sim --seeds 0,1,2,3,4
    python -m benchmarks.run_spread mr_damper_sim --changes '{"centre_bounds": [-1, 1]}'
    python -m benchmarks.run_spread f16 --seeds 0,1,2 --finished

``--cv``: each run's and the kept model's two-fold weights cross-validation beside them (the structure kept, the
weights refitted on one half of the estimation record, the free run scored on the other; the lower of the two
folds), the measurement of docs/engine-results.md, "Issue 37, round 6"::

    python -m benchmarks.run_spread piezo_sim,mr_damper_sim,bouc_wen_sim --cv

``--radius``: each run's local spectral radius along its estimation free run, the 99th percentile over the samples
(:func:`local_radius`: the companion matrix of the model's derivatives in its past outputs at each sample of its own
free run; above 1 the model is locally expanding there), the measurement of docs/engine-results.md, "Issue 37,
round 7"::

    python -m benchmarks.run_spread piezo_sim,mr_damper_sim,bouc_wen_sim,rlc,bouc_wen --radius

``--finished``: each admissible run's model is first given the final stage as if it were the kept one (the long
linear part when its score is under ``MORE_BELOW``, then the refinement judged out of sample), and the median and
mean are those runs'.

The figures of docs/engine-results.md, "Issue 37, round 3", come from this.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import dataclass

import numpy as np

from benchmarks.suite import Target, free_run_val, targets, validation_run
from streamid.engine import identify
from streamid.engine.choice.scores import RANGE_MARGIN
from streamid.engine.choice.longlinear import long_linear_choice
from streamid.model.narx import Model
from streamid.engine.fit.rbf import activations
from streamid.engine.choice.refine import ABOVE as REFINE_ABOVE, refine_judged
from streamid.engine.choice.selection import refit_weights
from streamid.engine.settings import DEFAULT, MORE_BELOW, RIDGE, CoEAConfig
from streamid.engine.validation import r2

#: A run whose estimation score is at most this left no admissible candidate (streamid.engine.choice.selection).
INADMISSIBLE = -1e9


@dataclass(frozen=True)
class Spread:
    """One identification's runs on the validation experiment (R²; nan: no finite run to combine)."""

    kept: float
    median: float
    mean: float
    runs_val: tuple[float, ...]
    runs_est: tuple[float, ...]
    kept_cv: float = float("nan")
    runs_cv: tuple[float, ...] = ()
    runs_radius: tuple[float, ...] = ()


def _free_run_r2(model: Model, u: np.ndarray, y: np.ndarray) -> float:
    """``model``'s free-run R^2 on ``(u, y)`` from its first ``max_lag`` outputs (-inf: it left the numbers)."""
    L = model.max_lag
    with np.errstate(all="ignore"):
        sim = model.simulate(u, y[:L])
    return r2(y[L:], sim[L:]) if np.all(np.isfinite(sim)) else float("-inf")


def local_radius(model: Model, u: np.ndarray, y: np.ndarray, quantile: float = 0.99) -> float:
    """The ``quantile`` over the samples of a single network's local spectral radius along its free run on ``(u, y)``:
    at each sample, the largest root of the companion matrix of ``d yhat / d y(t-k)`` (normalised units, the
    Gaussians' and the linear part's) at the model's own past outputs (inf: the free run left the numbers)."""
    L = model.max_lag
    with np.errstate(all="ignore"):
        sim = model.simulate(u, y[:L])
    if not np.all(np.isfinite(sim)):
        return float("inf")
    r, _ = model.regressor_rows(u, sim)
    phi = activations(r, model.centres, model.widths)
    own = [(j, g.lag) for j, g in enumerate(model.regressors) if g.signal == "y"]
    lin = []
    if model.linear is not None:
        regs = model.regressors if model.linear_regressors is None else model.linear_regressors
        lin = [(j, g.lag) for j, g in enumerate(regs) if g.signal == "y"]
    order = max([lag for _, lag in own + lin], default=0)
    if order == 0:
        return 0.0  # no output feedback: the free run is the input's alone
    step = max(1, r.shape[0] // 2000)  # 2,000 samples of the run are plenty for a quantile
    a = np.zeros((len(range(0, r.shape[0], step)), order))
    for j, lag in own:
        slope = -(r[::step, j:j + 1] - model.centres[None, :, j]) / model.widths[None, :] ** 2
        a[:, lag - 1] += (phi[::step] * slope) @ model.weights
    for j, lag in lin:
        a[:, lag - 1] += model.linear[j]  # type: ignore[index]
    companion = np.zeros((a.shape[0], order, order))
    companion[:, 0, :] = a
    companion[:, np.arange(1, order), np.arange(order - 1)] = 1.0
    return float(np.quantile(np.abs(np.linalg.eigvals(companion)).max(axis=1), quantile))


def two_fold(model: Model, t: Target) -> float:
    """The lower of ``model``'s two folds: weights refitted on one half of the estimation record (structure kept),
    free run over the other half."""
    u, y = t.u_est.reshape(len(t.y_est), -1), t.y_est
    h = len(y) // 2
    folds = []
    for fit, score in ((slice(0, h), slice(h, None)), (slice(h, None), slice(0, h))):
        half = refit_weights(model, u[fit], y[fit], RIDGE)
        folds.append(_free_run_r2(half, u[score], y[score]))
    return min(folds)


def finished(model: Model, run: int, score: float, t: Target, cfg: CoEAConfig) -> Model:
    """``model`` given identify's final stage as if it were the kept one (long linear part, then refinement)."""
    u, y = t.u_est.reshape(len(t.y_est), -1), t.y_est
    if cfg.long_linear and score < MORE_BELOW:
        ll, _ = long_linear_choice(model, score, cfg.long_linear, u, y, RANGE_MARGIN, RIDGE,
                                   [(run, model)], run)
        model = model if ll is None else ll
    if cfg.refine_iterations:
        model, _ = refine_judged(model, u, y, cfg.refine_iterations, REFINE_ABOVE, RANGE_MARGIN)
    return model


def spread(t: Target, changes: dict[str, object], seed: int, finish: bool = False, cv: bool = False,
           radius: bool = False) -> Spread:
    """One identification of ``t``: per run validation and estimation R², kept model's, median and mean of runs
    (``finish``: of the runs' :func:`finished` models; ``cv``: with each model's :func:`two_fold`; ``radius``: with
    each run's :func:`local_radius` on the estimation record)."""
    cfg = DEFAULT.replace(**changes)
    res = identify(t.u_est, t.y_est, cfg, seed)
    runs: tuple[Model, ...] = res.extra["run_models"]
    est = [float(s) for s in res.model.metrics.get("run_scores", [])]
    admissible = [k for k, s in enumerate(est) if s > INADMISSIBLE] or list(range(len(runs)))
    if finish:
        runs = tuple(finished(m, k, est[k], t, cfg) if k in admissible else m for k, m in enumerate(runs))
    paths = np.array([validation_run(runs[k], t) for k in admissible])
    paths = paths[np.all(np.isfinite(paths), axis=1)]
    first = max(m.max_lag for m in runs)
    median = mean = float("nan")
    if len(paths):
        median = r2(t.y_val[first:], np.median(paths, axis=0)[first:])
        mean = r2(t.y_val[first:], paths.mean(axis=0)[first:])
    return Spread(free_run_val(res.model, t), median, mean, tuple(free_run_val(m, t) for m in runs), tuple(est),
                  two_fold(res.model, t) if cv else float("nan"), tuple(two_fold(m, t) for m in runs) if cv else (),
                  tuple(local_radius(m, t.u_est.reshape(len(t.y_est), -1), t.y_est) for m in runs) if radius else ())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.run_spread", description=__doc__.split("\n\n")[0])
    ap.add_argument("systems", help="comma-separated names of benchmarks.suite.SYSTEMS")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated seeds (default 0-4)")
    ap.add_argument("--changes", default="{}", help="JSON object of CoEAConfig fields changed from the defaults")
    ap.add_argument("--finished", action="store_true", help="combine the runs given the final stage (see above)")
    ap.add_argument("--cv", action="store_true", help="each model's two-fold weights cross-validation (see above)")
    ap.add_argument("--radius", action="store_true", help="each run's local spectral radius (see above)")
    a = ap.parse_args(argv)
    changes = json.loads(a.changes)
    seeds = [int(s) for s in a.seeds.split(",")]
    for t in targets(tuple(a.systems.split(","))):
        rows = []
        for s in seeds:
            o = spread(t, changes, s, a.finished, a.cv, a.radius)
            rows.append(o)
            cv = (f"; two-fold kept {o.kept_cv:.4g}, runs {' '.join(f'{v:.4g}' for v in o.runs_cv)}"
                  if a.cv else "") + (f"; radius p99 {' '.join(f'{v:.4g}' for v in o.runs_radius)}" if a.radius else "")
            print(f"{t.name} seed {s}: kept {o.kept:.4g}, median of runs {o.median:.4g}, mean {o.mean:.4g}; "
                  f"runs val {' '.join(f'{v:.4g}' for v in o.runs_val)} "
                  f"(est {' '.join(f'{v:.4g}' for v in o.runs_est)}){cv}", flush=True)
        for key in ("kept", "median", "mean"):
            v = [float(getattr(o, key)) for o in rows]
            print(f"{t.name}: {key} median {statistics.median(v):.4g} worst {min(v):.4g}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
