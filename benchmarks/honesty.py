"""Issue 51: models that know when they do not know, measured on the suite's targets.

A measurement, not part of the engine. For each target and seed: the paper's plain procedure (``--paper``'s
settings, :data:`benchmarks.suite.SUITE_PAPER`) and the defaults' kept model, each with its free-run interval (both
calibrated by ``identify`` on the estimation record's held-out half), and the median of the defaults' restarts'
finished models (:func:`streamid.engine.choice.robust.median_of_finished`, calibrated the same way). Per model: the
validation free-run R^2 on the other experiment, the 90 % interval's coverage there and its mean width over the
output's standard deviation and over the free-run RMS error. ``--read`` prints per row the median / worst of the
seeds, the coverage (median over seeds) and the **silent failures**: seeds whose free-run R^2 is more than 0.05 under
the paper's median on the row and whose interval covers less than 80 % of the validation samples::

    python -m benchmarks.honesty piezo_sim,bouc_wen_sim --seeds 0,1,2,3,4 > rows.jsonl
    python -m benchmarks.honesty --read rows.jsonl
    python -m benchmarks.honesty --read rows.jsonl --beyond 1   # the same models, the band grown past the domain
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from dataclasses import replace
from typing import Any

import numpy as np

from benchmarks.ablation import SYSTEMS, _targets, print_rows, read_rows
from benchmarks.suite import SUITE_PAPER, Target, free_run_val, silent_failures, validation_band
from streamid.engine import identify
from streamid.engine.choice.calibration import with_interval
from streamid.engine.choice.robust import carries_long_linear, median_of_finished
from streamid.engine.settings import DEFAULT, RIDGE
from streamid.model.narx import Model

KINDS = ("paper", "kept", "median")
#: What ``--read`` summarises: the kinds scored, and ``hybrid``: the kept model where it carries a long linear part
#: (the networks alone free-ran the estimation record below MORE_BELOW, an estimation-record fact), else the median
#: of the finished restarts: the engine's rule since it was measured so (issue 51, :mod:`streamid.engine.choice.robust`);
#: on rows saved before it, what the rule would have kept; on rows saved after, the kept model itself.
SUMMARISED = (*KINDS, "hybrid")


def hybrid(row: dict[str, Any]) -> dict[str, Any]:
    """A row's ``hybrid`` score (see :data:`SUMMARISED`): the kept model's with a long linear part or no median."""
    kept = (row.get("models") or {}).get("kept")
    keep = row.get("median") is None or kept is None or carries_long_linear(Model.from_dict(kept))
    return dict(row["kept"] if keep else row["median"])


def _score(model: Model, t: Target) -> dict[str, Any]:
    fr = free_run_val(model, t)
    return {"fr_val": fr if math.isfinite(fr) else -1e300, "band": validation_band(model, t)}


def _row(job: tuple[str, int, int]) -> dict[str, Any]:
    system, index, seed = job
    t = _targets(system)[index]
    out: dict[str, Any] = {"target": t.name, "seed": seed}
    paper = identify(t.u_est, t.y_est, SUITE_PAPER, seed).model
    out["paper"] = _score(paper, t)
    res = identify(t.u_est, t.y_est, DEFAULT, seed)
    out["kept"] = _score(res.model, t)
    models = list(res.extra.get("run_models") or ())
    scores = [float(s) for s in res.model.metrics.get("run_scores", [])]
    med, ev = median_of_finished(models, scores, DEFAULT, t.u_est, t.y_est)
    med = None if med is None else with_interval(med, t.u_est, t.y_est, RIDGE)
    out["median"] = None if med is None else _score(med, t)
    out["median_evidence"] = {k: v for k, v in ev.items() if k != "finished"}
    # the models themselves (documents), so that another band rule can be scored on them without identifying again
    out["models"] = {"paper": paper.to_dict(), "kept": res.model.to_dict(),
                     "median": None if med is None else med.to_dict()}
    return out


def rescored(rows: list[dict[str, Any]], beyond: float) -> list[dict[str, Any]]:
    """The rows with every saved model's band scored again under the growth ``beyond`` past the estimation domain
    (:data:`streamid.model.uncertainty.BEYOND`; 0: the band without it): the same models, the same quantiles."""
    found: dict[str, Target] = {}
    out = []
    for r in rows:
        if r["target"] not in found:
            system = next(s for s in SYSTEMS if any(t.name == r["target"] for t in _targets(s)))
            found.update({t.name: t for t in _targets(system)})
        t = found[r["target"]]
        again = dict(r)
        for kind in KINDS:
            doc = (r.get("models") or {}).get(kind)
            if doc is None or r.get(kind) is None:
                continue
            m = Model.from_dict(doc)
            if m.interval is not None:
                m = replace(m, interval=replace(m.interval, beyond=beyond))
            again[kind] = {**r[kind], "band": validation_band(m, t)}
        out.append(again)
    return out


def summarise(rows: list[dict[str, Any]]) -> list[str]:
    """One line per target: per kind, median / worst FR val, coverage (median over seeds), width / std, silent."""
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(r["target"], []).append(r)
    lines, silent_total = [], dict.fromkeys(SUMMARISED, 0)
    for name, rs in by.items():
        paper_median = statistics.median(r["paper"]["fr_val"] for r in rs)
        cells = []
        for kind in SUMMARISED:
            got = [hybrid(r) if kind == "hybrid" else r[kind] if r.get(kind) is not None else r["kept"]
                   for r in rs]  # no median: the kept model stands
            frs = [g["fr_val"] for g in got]
            bands = [g["band"] for g in got if g["band"] is not None]
            cov = statistics.median(b["coverage"] for b in bands) if bands else math.nan
            wid = statistics.median(b["width_over_std"] for b in bands) if bands else math.nan
            wrms = statistics.median(b["width_over_rms"] for b in bands) if bands else math.nan
            silent = silent_failures(frs, [g["band"] for g in got], paper_median)
            silent_total[kind] += silent
            cells.append(f"{statistics.median(frs):.4f} / {min(frs):.4g}, cov {cov:.2f}, w/sd {wid:.2f}, "
                         f"w/rms {wrms:.2f}, silent {silent}")
        lines.append(f"| {name} ({len(rs)} seeds) | " + " | ".join(cells) + " |")
    lines.append("silent failures: " + ", ".join(f"{k} {v}" for k, v in silent_total.items()))
    return lines


#: Other ways of combining the same finished restarts, scored by :func:`combinations` on saved rows.
COMBINATIONS = ("median", "mean", "median+kept")


def combinations(rows: list[dict[str, Any]]) -> list[str]:
    """Per target, the validation free-run R^2 (median / worst of the seeds) of the saved median's members combined
    otherwise: their ``mean``, and the median of them and the kept model's members (``median+kept``); only the
    seeds where the engine's rule keeps the median (no long linear part, a median made). The same members, no new
    identification: what the rule "median" was chosen against (issue 51)."""
    from streamid.model.ensemble import EnsembleModel, members_of

    found: dict[str, Target] = {}
    by: dict[str, dict[str, list[float]]] = {}
    for r in rows:
        med_doc, kept_doc = (r.get("models") or {}).get("median"), (r.get("models") or {}).get("kept")
        if med_doc is None or kept_doc is None or carries_long_linear(kept := Model.from_dict(kept_doc)):
            continue
        if r["target"] not in found:
            system = next(s for s in SYSTEMS if any(t.name == r["target"] for t in _targets(s)))
            found.update({t.name: t for t in _targets(system)})
        t, med = found[r["target"]], Model.from_dict(med_doc)
        if not isinstance(med, EnsembleModel):
            continue
        members = (*members_of(med), *members_of(kept))
        got = by.setdefault(r["target"], {k: [] for k in COMBINATIONS})
        got["median"].append(float(r["median"]["fr_val"]))
        got["mean"].append(free_run_val(replace(med, combine="mean"), t))
        got["median+kept"].append(free_run_val(replace(med, members=members), t))
    return [f"| {name} ({len(got['median'])} seeds) | " + " | ".join(
        f"{statistics.median(v):.4f} / {min(v):.4g}" for v in got.values()) + " |" for name, got in by.items()]


def bundled(record: str, seeds: list[int]) -> list[str]:
    """The bundled records' half/half splits (:mod:`benchmarks.engine_cases`: the MR damper's 2,000 + 1,499 samples,
    the piezo P-885's halves) with the defaults: per seed the kept model's, the median's and the hybrid's validation
    free-run R^2 (see :data:`SUMMARISED`), then the median and the worst of each."""
    from benchmarks.engine_cases import mr_damper_data, piezo_data
    from streamid.engine.validation import r2_or_none

    ue, ye, uv, yv = {"mr_damper": mr_damper_data, "piezo_p885": piezo_data}[record]()
    ue, uv = ue.reshape(len(ye), -1), uv.reshape(len(yv), -1)

    def fr(m: Model) -> float:
        with np.errstate(all="ignore"):
            r = r2_or_none(yv[m.max_lag :], m.simulate(uv, yv[: m.max_lag])[m.max_lag :])
        return -math.inf if r is None else float(r)

    got: dict[str, list[float]] = {"kept": [], "median": [], "hybrid": []}
    lines = []
    for seed in seeds:
        res = identify(ue, ye, DEFAULT, seed)
        scores = [float(s) for s in res.model.metrics.get("run_scores", [])]
        med, _ = median_of_finished(list(res.extra.get("run_models") or ()), scores, DEFAULT, ue, ye)
        kept = fr(res.model)
        median = kept if med is None else fr(with_interval(med, ue, ye, RIDGE))
        hyb = kept if (med is None or carries_long_linear(res.model)) else median
        for k, v in (("kept", kept), ("median", median), ("hybrid", hyb)):
            got[k].append(v)
        lines.append(f"{record} seed {seed}: kept {kept:.6f} median {median:.6f} hybrid {hyb:.6f}")
    lines += [f"{record} {k}: median {statistics.median(v):.6f} worst {min(v):.6f}" for k, v in got.items()]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.honesty", description=(__doc__ or "").split("\n")[0])
    ap.add_argument("systems", nargs="?", default="", help="comma-separated suite systems, e.g. piezo_sim,rlc")
    ap.add_argument("--read", metavar="JSONL", help="summarise rows printed by an earlier run instead")
    ap.add_argument("--beyond", type=float, metavar="B",
                    help="with --read: score the saved models' bands again with this growth past the estimation "
                         "domain (streamid.model.uncertainty.BEYOND; 0: without it)")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--bundled", choices=("mr_damper", "piezo_p885"),
                    help="the bundled record's half/half split instead: kept, median and hybrid per seed")
    ap.add_argument("--combinations", action="store_true",
                    help="with --read: the saved medians' members combined otherwise (COMBINATIONS), FR val R^2")
    a = ap.parse_args(argv)
    if a.read and a.combinations:
        print("| target | " + " | ".join(COMBINATIONS) + " |")
        print("\n".join(combinations(read_rows(a.read))))
        return 0
    if a.bundled:
        print("\n".join(bundled(a.bundled, [int(s) for s in a.seeds.split(",")])))
        return 0
    if a.read:
        print("| target | " + " | ".join(SUMMARISED) + " |")
        rows = read_rows(a.read)
        print("\n".join(summarise(rows if a.beyond is None else rescored(rows, a.beyond))))
        return 0
    if not a.systems:
        ap.error("name the systems to run, or --read a file of rows")
    print_rows(a.systems, a.seeds, a.jobs, _row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
