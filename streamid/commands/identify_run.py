"""``streamid identify``'s work: the runs, their validation and the report (the options are in
:mod:`streamid.commands.identify`, which imports this module only when the command runs).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any, TextIO

import numpy as np

from streamid.commands.identify_io import (Bar, check_rrd_target, draw_rrd, emit_report, load, r2_text, read_text,
                                           split_text)
from streamid.logs.datafile import Dataset
from streamid.engine.settings import MORE_BELOW, CoEAConfig
from streamid.model.domain import domain_text
from streamid.model.uncertainty import interval_text
from streamid.engine.choice.caveats import model_caveats, size_caveat
from streamid.engine.choice.complexity import parameter_count
from streamid.model.ensemble import members_of
from streamid.engine.search.fanout import fan_out
from streamid.engine.identification import identify
from streamid.model.narx import Model
from streamid.engine.search.coevolution import Progress
from streamid.engine.search.parallel import EvalHelper
from streamid.engine.validation import CorrelationTest, validate
from streamid.model.limits import CHUNK_ROWS

__all__ = ["identify_command", "identify_runs", "validated_run"]


def _one(job: dict[str, Any], helper: EvalHelper | None = None) -> dict[str, Any]:
    """One identification + validation (also a worker process's body); JSON-able result."""
    ds: Dataset = job["dataset"]
    cfg = CoEAConfig.from_dict(job["config"])
    res = identify(
        ds.u_est,
        ds.y_est,
        cfg,
        job["seed"],
        callback=job.get("callback"),
        input_names=ds.input_names,
        output_name=ds.output_name,
        window=ds.window(),
        helper=helper,
        workers=job.get("workers", 1),
    )
    if job.get("callback") is not None:  # the last stage of a long record's progress line
        job["callback"](Progress(1, 1, res.fitness, res.evaluations, "validation"))
    # in one thread: with the helper's (idle) core as a second one, 1,000,000 samples' validation took the same time
    # (1.25 against 1.14-1.22 s) and its peak RSS grew by its second allocator arena (384 -> 405 MiB, stagemem)
    return validated_run(res.model, ds, seed=job["seed"], seconds=res.seconds, evaluations=res.evaluations,
                         fitness=res.fitness, history=[float(f) for f in res.fitness_history],
                         osa_est=res.extra.get("osa_predictions_est"))


def validated_run(model: Model, ds: Dataset, *, seed: int, seconds: float, evaluations: int, fitness: float,
                  history: list[float], threads: int = 1, osa_est: np.ndarray | None = None) -> dict[str, Any]:
    """A run's row of the report: ``model`` validated on the data set (JSON-able; its figures only: a drawing
    validates again). A free run that diverges is a row with its R² None and the sample it diverged at
    (``diverged``), never an error (issue 37). ``threads``: the predictions in that many threads (the same row);
    ``osa_est``: the model's one-step predictions over the estimation record when the identification made them
    (``Result.extra``), not made again."""
    rep = validate(model, ds.u_est, ds.y_est, ds.u_val, ds.y_val, keep=False, threads=threads,
                   osa_predictions_est=osa_est)
    model = model.with_metrics(**{f"r2_{k}": v for k, v in rep.r2_dict().items()})
    return {
        "seed": seed,
        "seconds": seconds,
        "evaluations": evaluations,
        "fitness": fitness,
        "lags": model.lags,
        "regressors": model.labels(),
        "r2": rep.r2_dict(),  # a free run that diverged: None (null), its first non-finite sample in "diverged"
        "diverged": rep.diverged(),
        "correlation": {"est": rep.correlation_est.to_dict(), "val": rep.correlation_val.to_dict()},
        # the model's prediction interval and estimation domain on the validation record (streamid.model)
        "interval_val": rep.extra.get("interval_val"),
        "outside_domain_val": rep.extra.get("outside_domain_val", 0.0),
        "selection_score": model.metrics.get("selection_score"),
        "model": model.to_json(indent=None),
        "history": history,
    }


def identify_runs(
    ds: Dataset,
    cfg: CoEAConfig,
    seeds: list[int],
    workers: int,
    bar: Bar | None = None,
    helper: EvalHelper | None = None,
    restart_workers: int = 1,
) -> list[dict[str, Any]]:
    """Run one identification per seed (over ``workers`` processes when several) and validate each.

    ``helper`` (an :class:`EvalHelper`) is used by the runs made in this process; ``restart_workers``: processes
    for one identification's restarts (``identify``'s ``workers``).
    """
    jobs = [{"dataset": ds, "config": cfg.to_dict(), "seed": s, "workers": restart_workers} for s in seeds]
    if bar is not None and (len(jobs) == 1 or workers <= 1):  # runs made here report every generation
        for i, job in enumerate(jobs):
            run = f"run {i + 1}/{len(jobs)}: " if len(jobs) > 1 else ""
            job["callback"] = lambda p, run=run: bar.generation(p, run)
    if len(jobs) == 1:
        return [_one(jobs[0], helper)]

    def progress(out: list[dict[str, Any]]) -> None:
        if bar is not None:
            bar.update(len(out), len(jobs), f"run {len(out)}/{len(jobs)}")

    return fan_out(_one, jobs, workers, helper=helper, on_result=progress)


def _stats(values: list[float | None]) -> dict[str, float | int | None]:
    """min/max/mean/std/median of the values that exist (None: a free run that diverged, counted in "diverged")."""
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    diverged = len(values) - a.size
    if a.size == 0:
        return {"min": None, "max": None, "mean": None, "std": None, "median": None, "diverged": diverged}
    return {
        **({"diverged": diverged} if diverged else {}),
        "min": float(a.min()),
        "max": float(a.max()),
        "mean": float(a.mean()),
        "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "median": float(np.median(a)),
    }


def _best_index(runs: list[dict[str, Any]], cfg: CoEAConfig) -> int:
    """The run whose model is kept: the identification's own rule (never the validation data)."""
    if cfg.selection == "fitness":
        return int(np.argmin([r["fitness"] for r in runs]))
    if cfg.selection == "fr_est":  # a run whose estimation free run diverged (None) is never kept over one that did not
        return int(np.argmax([-np.inf if r["r2"]["fr_est"] is None else r["r2"]["fr_est"] for r in runs]))
    return int(np.argmax([r["selection_score"] for r in runs]))


def _lags_text(run: dict[str, Any]) -> str:
    """The run's lags in streamid's one vocabulary (:meth:`Model.lags_text`)."""
    return Model.from_json(run["model"]).lags_text()


def _long_linear_line(ll: dict[str, Any] | None, gate: float) -> str:
    """The report's line on the long linear part: not tried, taken (order, evidence) or not taken."""
    if ll is None:
        return f"long linear part: not tried (the networks' estimation FR R2 is at least {gate:g})\n"
    tried = ", ".join(f"{o['order']}: " + ("not admissible" if o["criterion"] is None else f"{o['r2_fr_est']:.4f}")
                      for o in ll["orders"])
    cw = "none" if ll["criterion_without"] is None else f"{ll['criterion_without']:.1f}"
    nets = ll.get("networks") or []
    head = (f"long linear part of order {ll['order']} taken (FR R2 est {ll['r2_fr_est']:.5f}, criterion "
            f"{ll['criterion']:.1f} against {cw} without; on restart {ll['run']}'s network"
            + (f", the lowest criterion of the {len(nets)} restarts' networks offered)" if len(nets) > 1 else ")")
            + "".join(f"; the mean of the best {len(m['members'])} (restarts {', '.join(str(r) for r in m['members'])}) "
                      f"taken (its criterion lower)" for m in ll.get("means", []) if m["taken"])
            if ll["taken"]
            else "long linear part not taken" + (f" ({ll['reason']})" if "reason" in ll else
                                                 " (no order lowered the criterion with a free run better than the "
                                                 "mean and in range over a second pass)"))
    return head + (f"; orders (FR R2 est): {tried}\n" if tried else "\n")


def _ensemble_lines(cx: dict[str, Any]) -> list[str]:
    """The report's lines on the ensembles of the restarts' networks (``metrics.complexity.ensembles``)."""
    ens = cx.get("ensembles")
    if ens is None:
        return []
    if not ens:
        return ["ensembles of the restarts' networks: none (fewer than 2 admissible restarts)\n"]
    rows = "; ".join(
        f"{e['name']} (restarts {', '.join(str(i) for i in e['members'])}, p {e['params']:g}, "
        + ("not admissible" if e["criterion"] is None else f"FR R2 est {e['r2_fr_est']:.5f}, {e['criterion']:.1f}")
        + (", taken" if e["taken"] else "") + ")" for e in ens)
    taken = [e for e in ens if e["taken"]]
    verdict = (f"the best: the mean of {len(taken[0]['members'])} networks ({' + '.join(str(n) for n in taken[0]['neurons'])}"
               " neurons)" if taken else "the best: the single network (no mean had a lower criterion)")
    return [f"ensembles of the restarts' networks by {cx['rule']} (mean of the members' free runs): {rows}; {verdict}\n"]


def _robust_line(rb: dict[str, Any]) -> str:
    """The report's line on the median of the finished restarts (``metrics.complexity.robust``)."""
    if not rb.get("taken"):
        return f"restarts combined: no ({rb.get('reason', 'not made')})\n"
    steps = rb.get("finished", [])
    runs = ", ".join(str(s["run"]) for s in steps)
    refined = sum(1 for s in steps if s["refined"])
    ll = sum(1 for s in steps if s["long_linear"])
    return (f"restarts combined: kept the median of the {len(steps)} finished restarts' networks ({runs}), FR R2 est "
            f"{rb['r2_fr_est']:.5f}; each finished as a kept model is: " + (f"given a long linear part in {ll}, " if ll else "")
            + f"weights refined to the free run in {refined} (held out: refined on the first half, kept if the second "
            "half's FR R2 rose)\n")


def _print_report(out: TextIO, ds: Dataset, cfg: CoEAConfig, runs: list[dict[str, Any]], best: int, wall: float,
                  caveats: list[str]) -> None:
    w = out.write
    w(f"streamid identify: {ds.path}\n")
    w(f"  model     {', '.join(ds.input_names)} -> {ds.output_name}\n")
    w(f"  read      {read_text(ds.info, ds.period_ns, ds.n_est + ds.n_val)}\n")
    val = ds.info.get("validation")
    if val is not None:
        w(f"  read val  {val['path']}: {read_text(val, ds.period_ns, ds.n_val)}\n")
    w(f"  data      {split_text(ds)}\n")
    w(
        f"  settings  neurons {cfg.neurons}, max lag y {cfg.max_lag_y} / u {cfg.max_lag_u}"
        + (f" (raised from the data up to {cfg.max_lag_cap})" if cfg.max_lag_cap else "")
        + f", generations {cfg.generations}, "
        f"population {cfg.population}, restarts {cfg.restarts}, selection {cfg.selection}"
        + (
            f", lag search with {cfg.lag_search_neurons} neurons for {cfg.generations} generations"
            if cfg.lag_search_neurons
            else ""
        )
        + "\n\n"
    )
    header = f"{'run':>4} {'seed':>6} {'seconds':>8} {'evals':>7} {'fitness':>11} {'OSA est':>9} {'OSA val':>9} {'FR est':>9} {'FR val':>9}  lags"
    w(header + "\n")
    for i, r in enumerate(runs):
        m = "*" if i == best else " "
        r2d = r["r2"]
        w(
            f"{i:>3}{m} {r['seed']:>6} {r['seconds']:>8.2f} {r['evaluations']:>7} {r['fitness']:>11.5g} "
            f"{r2d['osa_est']:>9.5f} {r2d['osa_val']:>9.5f} {r2_text(r2d['fr_est'], 5, 9)} {r2_text(r2d['fr_val'], 5, 9)}  "
            f"{_lags_text(r)}\n"
        )
    if len(runs) > 1:
        st = _stats([r["fitness"] for r in runs])
        fr = _stats([r["r2"]["fr_val"] for r in runs])
        w("\nfitness over runs (OSA MSE on estimation data, output units^2; as the paper's Table 4):\n")
        w(f"  min {st['min']:.6g}  max {st['max']:.6g}  mean {st['mean']:.6g}  std {st['std']:.4g}\n")
        gone = f"; diverged in {fr['diverged']} of {len(runs)} runs" if fr.get("diverged") else ""
        w("FR R^2 on validation over runs: " + (f"min {fr['min']:.5f}  median {fr['median']:.5f}  max {fr['max']:.5f}"
                                                 if fr["min"] is not None else "none (every free run diverged)")
          + f"{gone}\n")
    b = runs[best]
    kept = Model.from_json(b["model"])  # parsed once; its metrics hold the evidence below
    k = len(members_of(kept))
    w(f"\nkept: run {best} (marked *; chosen by {cfg.selection} on the estimation data): {ds.output_name}(t) = "
      + (f"{getattr(kept, 'combine', 'mean')} of {k} networks on " if k > 1 else "") + f"F[{_lags_text(b)}]" + (" (the union of their lags)" if k > 1 else "")
      + (f" + {'each its own' if k > 1 else 'a'} linear ARX part of order {kept.linear_order}"
         if kept.linear_regressors else "") + "\n")
    for c in caveats:  # what to know before trusting it (streamid.engine.choice.caveats)
        w(f"caveat: {c}\n")
    made = kept.metrics
    if made.get("more_restarts") or made.get("fallback_runs"):  # runs beyond --restarts (streamid.engine.restarts)
        first = len(made["run_scores"]) - made.get("more_restarts", 0) - len(made.get("fallback_runs", ()))
        w(f"runs made: {first}" + (
            f" + {made['more_restarts']} more (the best of those fit the estimation record at FR R2 "
            f"{max(made['run_scores'][:first]):.5f}, in (0, {MORE_BELOW}))" if made.get("more_restarts") else "")
          + (f" + fallback runs of {', '.join(str(m) for m in made['fallback_runs'])} neurons" if made.get("fallback_runs") else "")
          + "\n")
    lag = made.get("max_lag_choice")
    if lag:  # the candidate lags 1..L chosen from the data (streamid.engine.search.lagspace)
        w(f"candidate lags 1..{lag['max_lag']} chosen from the data: input-output correlation peak at lag {lag['k_u']}, "
          f"output autocorrelation below 0.5 from lag {lag['k_y']} (floor {lag['floor']}, cap {lag['cap']})\n")
    ft = made.get("feedthrough")
    if ft:  # u(t) a candidate? (streamid.engine.search.feedthrough)
        lr = ", ".join(f"{name} {v:.1f}" for name, v in zip(ds.input_names, ft["lr"]))
        w(("direct terms u(t) are candidates: the output responds within the sample" if ft["min_lag_u"] == 0 else
           "direct terms u(t) are not candidates: no response within the sample was found")
          + f" (likelihood ratio of u(t) in a linear ARX model of order {ft['order']}: {lr}; threshold {ft['threshold']})\n")
    cx = made.get("complexity")
    if cx:  # the network size chosen among the restarts' candidates (streamid.engine.choice.complexity)
        w(f"complexity by {cx['rule']} on the estimation free run: {cx['neurons']} neurons (restart {cx['chosen_run']});"
          " candidates (neurons, lags 1..L, weights p, FR R2 est, criterion): "
          + "; ".join(f"{c['neurons']}, 1..{c['lag_space']}, {c['params']}, "
                      + ("not admissible" if c["criterion"] is None else f"{c['r2_fr_est']:.5f}, {c['criterion']:.1f}")
                      for c in cx["candidates"]) + "\n")
        for line in _ensemble_lines(cx):
            w(line)
    if cfg.linear_terms and cfg.selection == "fr_est":  # both kinds offered (CoEAConfig.linear_terms)
        nets = members_of(kept)
        with_lin = sum(m.linear is not None for m in nets)
        w("direct linear part a'r + b: " + (
            ("kept" if with_lin else "not kept") if len(nets) == 1 else f"in {with_lin} of the {len(nets)} networks")
          + " (every candidate was offered with and without one, the kind chosen by aic)\n")
    ll = (cx or {}).get("long_linear")
    if cfg.long_linear and cx:  # a dense linear ARX part (streamid.engine.choice.longlinear)
        w(_long_linear_line(ll, MORE_BELOW))
    rb = (cx or {}).get("robust")
    if rb:  # the finished restarts' median (streamid.engine.choice.robust)
        w(_robust_line(rb))
    rf = made.get("refinement")
    if rf:  # the weights fitted to the free run (streamid.engine.choice.refine)
        held = rf.get("held_out") or {}
        w("weights refined to the free run: " + (
            f"{rf['iterations']} iterations, FR R2 est {rf['r2_fr_est_before']:.5f} -> {rf['r2_fr_est_after']:.5f}"
            + (f" (held out: refined on the first half, the second half's FR R2 {held['r2_fr_before']:.5f} -> "
               f"{held['r2_fr_after']:.5f})" if None not in (held.get("r2_fr_before"), held.get("r2_fr_after")) else "") + "\n"
            if rf["taken"] else f"no ({rf['reason']})\n"))
    nc = made.get("neuron_choice")
    if nc:  # the chosen run's network against its pruned versions (CoEAConfig.prune)
        w(f"neurons of the chosen run by {nc['rule']}: {nc['neurons']} of "
          + ", ".join(f"{c['neurons']} (" + ("not admissible" if c["criterion"] is None
                                             else f"FR R2 est {c['r2_fr_est']:.5f}, {c['criterion']:.1f}") + ")"
                      for c in nc["candidates"]) + "\n")
    if "interval_val" in b:  # the kept model's interval and domain on the validation record (streamid.model)
        w(interval_text(b["interval_val"], "validation") + "\n")
        w(domain_text(float(b["outside_domain_val"]), "validation") + "\n")
    for part, title in (("est", "estimation"), ("val", "validation")):
        c = b["correlation"][part]
        w(f"correlation tests on the {title} residual ({c['n']} samples, 95 % band ±{c['band']:.3g}):\n")
        for name, t in c["tests"].items():
            test = CorrelationTest(name, t["formula"], tuple(t["lags"]), tuple(t["values"]), float(c["band"]))
            w(f"  {test.verdict()}\n")
    w(f"wall time {wall:.2f} s\n")


def identify_command(args: argparse.Namespace, cfg: CoEAConfig) -> int:
    """``streamid identify``'s work, with its options ``args`` and their engine settings ``cfg``."""
    t0 = time.perf_counter()
    if args.rrd is not None:
        check_rrd_target(args.rrd)
    show = args.progress == "always" or (args.progress == "auto" and sys.stderr.isatty())
    # The runs go to a pool of `--workers` processes when there are several; otherwise (one run
    # of one coevolution, or --workers 1) they are made here, and with a second process
    # allowed an EvalHelper evaluates half of every batch (started now, while the data load).
    # With a progress bar, one run's restarts are made here too when the helper can take the
    # second core (the same result), so that the bar moves every generation, not once per
    # finished restart.
    bar_here = show and args.runs == 1 and args.workers >= 2 and EvalHelper.supported()
    # one identification's restarts over --workers processes when it is the only run and has no bar here
    restart_workers = args.workers if (args.runs == 1 and not bar_here) else 1
    in_process = (args.runs == 1 and (cfg.restarts == 1 or restart_workers <= 1)) or args.workers <= 1
    helper = EvalHelper(wait=False) if (args.workers >= 2 and in_process and EvalHelper.supported()) else None
    try:
        reading_bar = Bar(sys.stderr, show, "read", delay_s=1.0 if args.progress == "auto" else 0.0)
        try:  # the first stage of a long record's progress: its rows read
            ds = load(args, lambda done, total: reading_bar.update(done, total, f"{int(done):,} rows"))
        finally:
            reading_bar.close()
        for note in ds.notes:
            print(f"streamid identify: warning: {note}", file=sys.stderr, flush=True)
        if args.runs == 1 and len(ds.y_est) > CHUNK_ROWS:
            # A record beyond one chunk: its restarts here, one after the other, and the second core (when
            # allowed) evaluates half of every search batch in a helper. A pool's start and its copies of the record
            # cost more than its parallel restarts save (1,000,000 samples: in this process 16.4 s and 403 MB; a
            # pool of 2 13.1-13.5 s, 395 MB and two more processes holding the record; a helper 13.2-13.3 s and
            # 400-404 MB: docs/benchmarks.md, "Long records offline")
            restart_workers = 1
            if helper is None and args.workers >= 2 and EvalHelper.supported():
                helper = EvalHelper(wait=False)
        bar = Bar(sys.stderr, show, "identify", delay_s=1.0 if args.progress == "auto" else 0.0)
        seeds = list(range(args.seed, args.seed + args.runs))
        try:
            runs = identify_runs(ds, cfg, seeds, args.workers, bar, helper, restart_workers)
        finally:
            bar.close()
    finally:
        if helper is not None:
            helper.close()
    best = _best_index(runs, cfg)
    wall = time.perf_counter() - t0
    rrd_files = draw_rrd(args.rrd, ds, runs, best, cfg.generations) if args.rrd is not None else []
    caveats = model_caveats(runs[best]["r2"], ds.u_est, ds.y_est, ds.u_val, ds.y_val, ds.input_names, ds.output_name,
                            runs[best].get("diverged"))
    kept = Model.from_json(runs[best]["model"])
    caveats += size_caveat(parameter_count(kept), runs[best]["r2"]["fr_est"], kept.metrics.get("complexity"))
    if not args.json:
        _print_report(sys.stdout, ds, cfg, runs, best, wall, caveats)
        if rrd_files:
            print(f"rrd: {', '.join(rrd_files)} (streamid view {args.rrd}; --screenshot PNG renders it)")
    if args.model:
        model = Model.from_json(runs[best]["model"])
        with open(args.model, "w", encoding="utf-8") as fh:
            fh.write(model.to_json())
    if args.json or args.report:
        report = {
            "format": "streamid.identify_report/1",
            "data": {
                "path": ds.path,
                "inputs": list(ds.input_names),
                "output": ds.output_name,
                "n_est": ds.n_est,
                "n_val": ds.n_val,
                "validation_path": ds.validation_path,
                "read": ds.info,
                "warnings": list(ds.notes),
                "period_ns": ds.period_ns,
            },
            "config": cfg.to_dict(),
            "runs": [{k: v for k, v in r.items() if k not in ("model", "history")} for r in runs],
            "best": best,
            "caveats": caveats,
            "rrd": rrd_files,
            "summary": {
                "fitness": _stats([r["fitness"] for r in runs]),
                "r2": {k: _stats([r["r2"][k] for r in runs]) for k in ("osa_est", "osa_val", "fr_est", "fr_val")},
                "seconds": _stats([r["seconds"] for r in runs]),
                "evaluations": _stats([float(r["evaluations"]) for r in runs]),
                "wall_seconds": wall,
            },
        }
        emit_report(report, to_stdout=args.json, path=args.report)
    return 0
