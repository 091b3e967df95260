"""Issue 37, round 8: the kept model's network refitted as if its regressors were off by its own free-run error.

A measurement, not part of the engine. In a free run the output lags a network sees are off by the model's own
error; fitting the weights as if every regressor were perturbed by noise of that variance ``s2`` penalises, to
first order, the network's slope (Bishop 1995, "Training with noise is equivalent to Tikhonov regularization"):

    min_w  sum_t (y_t - yhat_t)^2 + s2 * sum_t ||d net(r_t) / d r_S||^2

with ``S`` the output lags (``"y"``) or every regressor (``"all"``) and ``s2`` the kept model's estimation
free-run mean squared error in normalised units. The refit is a least squares: a kept model whose weights the
engine fitted to its free run (the refinement) loses that fit, so the plain refit (``s2 = 0``, column ``refit``)
is reported too, to tell the penalty's effect from the refinement's removal. The linear part (if any) is refitted with the network and not
penalised; a refit whose linear autoregression leaves the unit circle is refused (the engine's rule).

Each row: the defaults' kept model on the suite's target, its validation free-run R^2 on the other experiment;
the penalised refit's on the whole estimation record; and, for the judged rule, the refits (penalised or not) on
the first half scored by their free run over the second half (both ``s2`` taken on that half); ``--read`` then
prints each row's median / worst and issue 37's verdict (:func:`benchmarks.ablation.verdict`) for the defaults,
the penalised refits, and the judged rule (the refit kept only if its half free-runs at least as well over the
second half as the plain refit of that half)::

    python -m benchmarks.gradient_penalty piezo_sim,bouc_wen_sim --seeds 0,1,2,3,4 > rows.jsonl
    python -m benchmarks.gradient_penalty --read rows.jsonl
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.ablation import _targets, print_rows, read_rows, verdict
from benchmarks.suite import free_run_val
from streamid.engine import identify
from streamid.model.ensemble import EnsembleModel
from streamid.model.narx import Model
from streamid.engine.fit.rbf import activations
from streamid.engine.settings import DEFAULT, RIDGE
from streamid.engine.choice.stability import radius

Array = NDArray[np.float64]


def gradient_gram(r: Array, centres: Array, widths: Array, columns: list[int]) -> Array:
    """``G`` with ``w' G w = sum_t ||d/d r_S sum_m w_m phi_m(r_t)||^2`` over the columns ``S`` of ``r`` (n x k)."""
    a = activations(r, centres, widths) / widths[None, :] ** 2  # d phi_m / d r_j = -(r_j - c_mj) / s_m^2 phi_m
    g = np.zeros((centres.shape[0],) * 2)
    for j in columns:
        b = a * (r[:, j : j + 1] - centres[None, :, j])
        g += b.T @ b
    return g


def penalised_refit(model: Model, u: Array, y: Array, s2: float, which: str) -> Model | None:
    """``model``'s weights (and linear part) refitted on ``(u, y)`` with the slope penalty ``s2`` on ``which``
    (``"y"``: the output lags, ``"all"``: every regressor); an ensemble member by member. None: a linear
    autoregression left the unit circle."""
    if isinstance(model, EnsembleModel):
        members = [penalised_refit(m, u, y, s2, which) for m in model.members]
        if any(m is None for m in members):
            return None
        it = iter(members)
        return model.map_members(lambda _m: next(it))  # type: ignore[arg-type,return-value]
    r, target = model.regressor_rows(u, y)
    phi = activations(r, model.centres, model.widths)
    cols = [j for j, g in enumerate(model.regressors) if which == "all" or g.signal == "y"]
    M = model.neurons
    x = phi if model.linear is None else np.hstack(
        [phi, r if model.linear_regressors is None else model.linear_rows(u, y), np.ones((len(target), 1))])
    h = x.T @ x
    h[:M, :M] += s2 * gradient_gram(r, model.centres, model.widths, cols)
    h += RIDGE * np.mean(np.diag(h)) * np.eye(h.shape[0])
    sol = np.linalg.solve(h, x.T @ target)
    if model.linear is None:
        return replace(model, weights=sol[:M])
    lin = np.concatenate([sol[M:-1], sol[-1:]])
    if not radius(model.regressors if model.linear_regressors is None else model.linear_regressors, lin[:-1]) < 1.0:
        return None
    return replace(model, weights=sol[:M], linear=lin)


def free_run_mse(model: Model, u: Array, y: Array) -> float:
    """The mean squared error of ``model``'s free run over ``(u, y)`` in normalised output units (inf: diverged)."""
    L = model.max_lag
    with np.errstate(all="ignore"):
        e = model.normalisation.y(model.simulate(u, y[:L])[L:]) - model.normalisation.y(y[L:])
    return float(np.mean(e**2)) if np.all(np.isfinite(e)) else float("inf")


def _held_out(model: Model | None, u: Array, y: Array, h: int) -> float | None:
    """Free-run R^2 over samples ``h..`` (simulated from the record's start); None: refused or diverged."""
    if model is None:
        return None
    with np.errstate(all="ignore"):
        e = model.simulate(u, y[: model.max_lag])[h:] - y[h:]
    return float(1.0 - np.sum(e**2) / np.sum((y[h:] - y[h:].mean()) ** 2)) if np.all(np.isfinite(e)) else None


def row(system: str, index: int, seed: int) -> dict[str, Any]:
    """One target and seed: the kept model's validation R^2, the penalised refits', the held-out half's."""
    t = _targets(system)[index]
    u, y = t.u_est, t.y_est
    model = identify(u, y, DEFAULT, seed).model
    h = len(y) // 2
    out: dict[str, Any] = {"row": t.name, "seed": seed, "base": free_run_val(model, t)}
    plain = penalised_refit(model, u, y, 0.0, "y")  # the least squares again: a refined model loses its refinement
    out["refit"] = None if plain is None else free_run_val(plain, t)
    half = penalised_refit(model, u[:h], y[:h], 0.0, "y")
    out["held_base"] = _held_out(half, u, y, h)
    s2, s2_half = free_run_mse(model, u, y), free_run_mse(half if half is not None else model, u[:h], y[:h])
    for which in ("y", "all"):
        pm = penalised_refit(model, u, y, s2, which)
        out[which] = None if pm is None else free_run_val(pm, t)
        out["held_" + which] = _held_out(penalised_refit(model, u[:h], y[:h], s2_half, which), u, y, h)
    return out


def _row(job: tuple[str, int, int]) -> dict[str, Any]:
    return row(*job)


def _or_kept(o: dict[str, Any], key: str) -> float:
    """A refit refused (its autoregression left the unit circle) is not made: the kept model stays."""
    return float(o["base"]) if o[key] is None else float(o[key])


def _judged(o: dict[str, Any], which: str) -> float:
    if o[which] is None or o["held_" + which] is None:
        return float(o["base"])
    keep = o["held_base"] is None or o["held_" + which] >= o["held_base"]
    return float(o[which]) if keep else float(o["base"])


#: The columns of :func:`summarise`: the defaults, the penalised refits, and each judged out of sample.
COLUMNS = {
    "defaults": lambda o: float(o["base"]),
    "refit": lambda o: _or_kept(o, "refit"),
    "y": lambda o: _or_kept(o, "y"),
    "all": lambda o: _or_kept(o, "all"),
    "y judged": lambda o: _judged(o, "y"),
    "all judged": lambda o: _judged(o, "all"),
}


def summarise(rows: list[dict[str, Any]]) -> tuple[list[str], dict[str, int]]:
    """One line per target (median / worst per column, ``*`` where issue 37's targets are met) and the count met."""
    by: dict[str, list[dict[str, Any]]] = {}
    for o in rows:
        by.setdefault(o["row"], []).append(o)
    lines, met = [], dict.fromkeys(COLUMNS, 0)
    for name, obs in by.items():
        cells = []
        for col, f in COLUMNS.items():
            vals = [v if math.isfinite(v) else -1e300 for v in map(f, obs)]
            med, worst = statistics.median(vals), min(vals)
            ok = verdict(name, med, worst) == "met"
            met[col] += ok
            cells.append(f"{med:.4f} / {worst:.4g}{' *' if ok else ''}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines, met


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.gradient_penalty", description=__doc__.split("\n")[0])
    ap.add_argument("systems", nargs="?", default="", help="comma-separated suite systems, e.g. piezo_sim,rlc")
    ap.add_argument("--read", metavar="JSONL", help="summarise rows printed by an earlier run instead")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    if a.read:
        lines, met = summarise(read_rows(a.read))
        print("| target | " + " | ".join(COLUMNS) + " |")
        print("\n".join(lines))
        print("targets met: " + ", ".join(f"{k} {v}" for k, v in met.items()))
        return 0
    if not a.systems:
        ap.error("name the systems to run, or --read a file of rows")
    print_rows(a.systems, a.seeds, a.jobs, _row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
