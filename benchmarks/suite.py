"""``streamid bench --suite``: the engine on data it was not tuned on, system by system.

A model is judged on *another experiment* (another excitation type, spectrum or amplitude), not only on the
second half of the record it was fitted on (issue 37). The primary rows are such pairs; the half/half splits of
single records stay as secondary rows.

Two-experiment rows (estimation on one experiment, validation on another)
--------------------------------------------------------------------------
==========================  ==========================================================  =============
system                      estimation -> validation                                    est / val
==========================  ==========================================================  =============
piezo_sim, mr_damper_sim,   three pairs per simulated device (:mod:`benchmarks.experiments`): two   see there
bouc_wen_sim, reactor_sim   inside the estimation's range, one a step beyond it
f16                         F-16 GVT, measured: level 3 multisine -> level 2 (files)    8192 / 8192
rlc                         nonlinear RLC circuit, simulated by its authors: filtered   10000 / 10000
                            noise 80 V / 150 kHz -> 60 V / 200 kHz (``rlc_id`` -> ``rlc_test``)
bouc_wen                    Bouc-Wen benchmark: 10,000 samples of a 5-150 Hz multisine  10000 / 153000
                            from :func:`streamid.sim.simulate_bouc_wen_multisine` ->    and 8192
                            the benchmark's sine sweep, and its multisine (periodic)
==========================  ==========================================================  =============

Half/half rows (secondary: one record, its second half held out)
----------------------------------------------------------------
==============  =====================================================  ===================  =====================
system          source                                                 est / val samples    outputs
==============  =====================================================  ===================  =====================
ball_and_beam   DaISy, measured (``streamid/data/suite``)              500 / 500            ball position
heat_exchanger  DaISy, measured (``streamid/data/suite``)              2000 / 2000          outlet temperature
robot_arm       DaISy, measured (``streamid/data/suite``)              512 / 512            arm acceleration
cstr            DaISy, simulated (bundled log ``cstr``)                3750 / 3750          Ca, T
mr_damper       measured (bundled log ``mr_damper``)                   2000 / 1499          force
piezo_p885      measured (bundled log ``piezo_p885``)                  4013 / 4014          displacement
reactor         :func:`streamid.sim.simulate_reactor` (paper eq. 17)   480 / 480            molecular weight
==============  =====================================================  ===================  =====================

The figure is the free-run R^2 on the validation part, the simulation started from
its first ``max_lag`` measured outputs; a free run that diverges (non-finite) counts as -inf
and is reported as such. The F-16 files and the Bouc-Wen multisine are one steady-state period
each: the free run goes through the validation period twice and the second pass is scored (the
first warms the simulation up), for streamid and the peers alike.

Per system: median and min over 10 seeds (:data:`SUITE_SEEDS`) of the paper's settings (one run,
G = 400, M = 10, lags 1..10, chosen by fitness) and of the defaults
(:data:`~streamid.engine.settings.DEFAULT`), seconds per identification, and with
``--peers`` the best SysIdentPy FROLS of a lag/degree grid, each setting with and
without the input's current sample ``u(t)`` (deterministic, one fit each; the best of
the grid *on the validation data*: generous to the peer). ``--systems a,b`` runs only those.

Honesty (issue 51), per system and setting: the 90 % free-run interval's coverage of the validation samples and
its mean width (over the output's standard deviation and over the free run's RMS error), and the **silent
failures**: seeds whose free-run R^2 is more than 0.05 under the paper's median on the row and whose interval covers
less than 80 % of the validation samples (a model wrong on the next experiment that does not say so); their sum
over the two-experiment rows is the last line.
"""

from __future__ import annotations

import itertools
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from streamid.model.ensemble import members_of
from streamid.engine.identification import identify
from streamid.model.narx import Model
from streamid.engine.search.parallel import EvalHelper
from streamid.engine.settings import DEFAULT, PAPER, CoEAConfig
from streamid.engine.validation import r2
from streamid.model.uncertainty import DEFAULT_LEVEL, Band, band_coverage

__all__ = ["Target", "SYSTEMS", "targets", "free_run_val", "validation_run", "validation_band", "silent_failures",
           "run_suite", "run_table", "bench"]

SUITE_PAPER = PAPER.replace(neurons=10, generations=400)
#: Seeds of ``streamid bench --suite`` (issue 51: the worst of 10 is the figure a user meets).
SUITE_SEEDS = 10
#: A *silent failure* (issue 51): a seed whose validation free-run R^2 is more than SILENT_GAP under the paper's
#: median on the row and whose 90 % interval covers less than SILENT_COVERAGE of the validation samples: a model
#: that is wrong on the next experiment and does not say so.
SILENT_GAP = 0.05
SILENT_COVERAGE = 0.8


@dataclass(frozen=True, eq=False)
class Target:
    """One output of one system: estimation and validation arrays (``u`` of shape (N, n_inputs))."""

    system: str
    output: str
    u_est: np.ndarray
    y_est: np.ndarray
    u_val: np.ndarray
    y_val: np.ndarray
    periodic_val: bool = False
    #: "two-experiment" (validation on another experiment: the primary rows) or "half" (one record's halves)
    kind: str = "half"
    #: the pair's name (estimation -> validation) when a system has several
    label: str = ""

    @property
    def name(self) -> str:
        base = self.system if self.output == "" else f"{self.system}:{self.output}"
        return f"{base} [{self.label}]" if self.label else base


def _suite_file(name: str) -> Path:
    return Path(str(resources.files("streamid") / "data" / "suite" / name))


def _csv(name: str) -> dict[str, np.ndarray]:
    path = _suite_file(name)
    with open(path, encoding="utf-8") as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {h: data[:, i] for i, h in enumerate(header)}


def _split(system: str, output: str, u: np.ndarray, y: np.ndarray, n_est: int) -> Target:
    u2 = u.reshape(len(u), -1)
    return Target(system, output, u2[:n_est], y[:n_est], u2[n_est:], y[n_est:])


@lru_cache(maxsize=None)
def _log(name: str) -> Any:
    from streamid.logs import bundled_log, read_log_arrays

    return read_log_arrays(bundled_log(name))


def _daisy(name: str, inp: str, out: str, n_est: int) -> list[Target]:
    d = _csv(f"{name}.csv")
    return [_split(name, "", d[inp], d[out], n_est)]


def _bundled(name: str, n_est: int | None = None, periodic: bool = False, kind: str = "half") -> list[Target]:
    arr = _log(name)
    (u,) = (np.asarray(v, dtype=np.float64) for v in arr.inputs.values())
    k = len(u) // 2 if n_est is None else n_est
    outs = list(arr.outputs.items())
    return [
        Target(name, "" if len(outs) == 1 else key, u[:k, None], np.asarray(y, dtype=np.float64)[:k],
               u[k:, None], np.asarray(y, dtype=np.float64)[k:], periodic, kind)
        for key, y in outs
    ]


@lru_cache(maxsize=2)
def _bouc_wen(n_est: int) -> list[Target]:
    from streamid.sim import simulate_bouc_wen_multisine

    est = simulate_bouc_wen_multisine(n_est, 0)
    with np.load(_suite_file("bouc_wen_sinesweep.npz"), allow_pickle=False) as z:
        uv, yv = np.asarray(z["u_N"]), np.asarray(z["y_m"])
    ms = _csv("bouc_wen_multisine.csv")
    return [Target("bouc_wen", "", est.u[:, None], est.y, uv[:, None], yv, kind="two-experiment", label="sweep"),
            Target("bouc_wen", "", est.u[:, None], est.y, ms["u_N"][:, None], ms["y_m"], periodic_val=True,
                   kind="two-experiment", label="multisine")]


def _rlc() -> list[Target]:
    est, val = _csv("rlc_id.csv"), _csv("rlc_test.csv")
    return [Target("rlc", "", est["V_IN"][:, None], est["V_C"], val["V_IN"][:, None], val["V_C"],
                   kind="two-experiment", label="id->test")]


def _simulated(system: str) -> Callable[[], list[Target]]:
    def load() -> list[Target]:
        from benchmarks.experiments import pair

        return [Target(e.system, "", e.u_est, e.y_est, e.u_val, e.y_val, kind="two-experiment",
                       label=e.label + (", beyond" if e.beyond else "")) for e in pair(system)]
    return load


def _reactor() -> list[Target]:
    from streamid.sim import simulate_reactor

    _, u, y = simulate_reactor(960, 0)
    return [_split("reactor", "", np.asarray(u), np.asarray(y), 480)]


#: name -> loader of its targets (one per output).
SYSTEMS: dict[str, Callable[[], list[Target]]] = {
    # two experiments (the primary rows)
    "piezo_sim": _simulated("piezo_sim"),
    "mr_damper_sim": _simulated("mr_damper_sim"),
    "bouc_wen_sim": _simulated("bouc_wen_sim"),
    "reactor_sim": _simulated("reactor_sim"),
    "f16": lambda: _bundled("f16_gvt", 8192, periodic=True, kind="two-experiment"),
    "rlc": _rlc,
    "bouc_wen": lambda: _bouc_wen(10_000),
    # one record's halves (secondary)
    "ball_and_beam": lambda: _daisy("ball_and_beam", "u", "y", 500),
    "heat_exchanger": lambda: _daisy("heat_exchanger", "q", "th", 2000),
    "robot_arm": lambda: _daisy("robot_arm", "u", "y", 512),
    "cstr": lambda: _bundled("cstr", 3750),
    "mr_damper": lambda: _bundled("mr_damper", 2000),
    "piezo_p885": lambda: _bundled("piezo_p885"),
    "reactor": _reactor,
}

#: The systems of ``--quick`` (a smoke run: small records).
QUICK_SYSTEMS = ("ball_and_beam", "robot_arm", "reactor")


def targets(names: tuple[str, ...] | None = None) -> list[Target]:
    """Every target of the named systems (default: all), in :data:`SYSTEMS` order."""
    return [t for name in (names or tuple(SYSTEMS)) for t in SYSTEMS[name]()]


def validation_run(model: Model, t: Target) -> np.ndarray:
    """``model``'s free run on the validation part, aligned with ``t.y_val`` (periodic: the second pass, whole;
    else from the measured first ``max_lag`` outputs on)."""
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        if t.periodic_val:
            return model.simulate(np.concatenate([t.u_val, t.u_val]), t.y_val[:L])[len(t.y_val) :]
        return model.simulate(t.u_val, t.y_val[:L])


def free_run_val(model: Model, t: Target) -> float:
    """Free-run R^2 of ``model`` on the validation part (periodic: the second pass scored);
    -inf when the free run diverges (only a model with a linear part can: its output is unbounded)."""
    first = 0 if t.periodic_val else model.max_lag
    sim, ref = validation_run(model, t)[first:], t.y_val[first:]
    if not np.all(np.isfinite(sim)):
        return float("-inf")
    return r2(ref, sim)


def validation_band(model: Model, t: Target) -> dict[str, Any] | None:
    """The model's 90 % band on the validation part, scored as :func:`free_run_val` scores the free run (periodic:
    the second pass): ``coverage``, ``width``, ``width_over_std``, ``width_over_rms`` (over the free run's RMS
    error there); None when the model carries no interval."""
    if model.interval is None:
        return None
    L = model.max_lag
    with np.errstate(over="ignore", invalid="ignore"):
        if t.periodic_val:
            b = model.simulate(np.concatenate([t.u_val, t.u_val]), t.y_val[:L], interval=DEFAULT_LEVEL)
            n = len(t.y_val)
            band, start = Band(b.y[n:], b.lower[n:], b.upper[n:]), 0
        else:
            band, start = model.simulate(t.u_val, t.y_val[:L], interval=DEFAULT_LEVEL), L
        got = band_coverage(t.y_val, band, start)
        rms = float(np.sqrt(np.mean((t.y_val[start:] - band.y[start:]) ** 2)))
    return {**got, "width_over_rms": got["width"] / rms if rms > 0 and np.isfinite(rms) else float("inf")}


def silent_failures(fr_vals: list[float], bands: list[dict[str, Any] | None], paper_median: float) -> int:
    """How many seeds failed silently (:data:`SILENT_GAP`, :data:`SILENT_COVERAGE`): a seed without an interval
    says nothing, so it counts when its free run is poor."""
    return sum(1 for fr, b in zip(fr_vals, bands) if fr < paper_median - SILENT_GAP
               and (b is None or b["coverage"] < SILENT_COVERAGE))


def identify_target(t: Target, cfg: CoEAConfig, seed: int, helper: EvalHelper | None = None) -> dict[str, Any]:
    """One identification of ``t`` with ``cfg``: validation free-run R^2, wall seconds, chosen structure.
    ``helper``: a started :class:`~streamid.engine.search.parallel.EvalHelper` (the second core; the same result)."""
    t0 = time.perf_counter()
    res = identify(t.u_est, t.y_est, cfg, seed, helper=helper)
    seconds = time.perf_counter() - t0
    fr = free_run_val(res.model, t)
    return {"fr_val": fr, "seconds": seconds, "lags": res.model.lags_text(), "neurons": res.model.neurons,
            "networks": len(members_of(res.model)),  # > 1: the mean of that many runs' networks (run_ensembles)
            "refined": bool((res.model.metrics.get("refinement") or {}).get("taken")),  # weights fitted to the free run
            "long_linear": int(((res.model.metrics.get("complexity") or {}).get("long_linear") or {}).get("order") or 0),
            "band": validation_band(res.model, t),  # its 90 % interval on the validation part
            "metrics": {k: v for k, v in res.model.metrics.items() if k != "fitness"}}


def run_table(t: Target, cfg: CoEAConfig, seed: int) -> dict[str, Any]:
    """One identification of ``t`` and every run's candidate after pruning, each validated: what the final
    choice had to choose among (size, lags, estimation free-run R^2, criterion) and what each would have
    scored on the validation part (``chosen``: the run taken). Only with a rule that keeps one model per run
    (``selection="fr_est"``, several restarts)."""
    res = identify(t.u_est, t.y_est, cfg, seed)
    comp = res.model.metrics.get("complexity")
    models = res.extra.get("run_models")
    if comp is None or models is None:
        raise ValueError(f"run_table needs selection='fr_est' and restarts > 1; got selection={cfg.selection!r}, "
                         f"restarts={cfg.restarts}")
    runs = [{"run": c["run"], "neurons": m.neurons, "lags": m.lags_text(), "r2_fr_est": c["r2_fr_est"],
             "criterion": c["criterion"], "fr_val": free_run_val(m, t), "chosen": c["run"] == res.chosen}
            for c, m in zip(comp["candidates"], models)]
    return {"target": t.name, "seed": seed, "fr_val": free_run_val(res.model, t), "chosen": res.chosen, "runs": runs}


def frols_best(t: Target, quick: bool = False) -> dict[str, Any]:
    """SysIdentPy FROLS (polynomial NARX, AIC among 20 terms, data scaled as streamid's) over a lag/degree grid.

    The grid also offers FROLS the input's current sample ``u(t)`` (its input lags start at 1, as the paper's
    did, so the input is advanced one sample: ``u'(t - 1) = u(t)``), since streamid's defaults offer ``u(t)``
    where a test finds a response within the sample (issue 13, round 10): the peer gets the same information.
    """
    from benchmarks.peers import fit_frols

    grid = [(2, 2)] if quick else [(lag, deg) for lag in (2, 5) for deg in (2, 3)]
    best: dict[str, Any] = {"fr_val": -np.inf, "seconds": 0.0, "setting": ""}
    for (lag, deg), direct, scale in itertools.product(grid, (False,) if quick else (False, True), (False, True)):
        ue, ye, uv, yv = ((t.u_est[1:], t.y_est[:-1], t.u_val[1:], t.y_val[:-1]) if direct
                          else (t.u_est, t.y_est, t.u_val, t.y_val))
        try:
            fit = fit_frols(ue, ye, uv, yv, max_lag=lag, degree=deg, n_info_values=20,
                            scale=scale, periodic=t.periodic_val)
        except Exception as exc:  # a peer that fails on one setting is reported, not fatal
            best.setdefault("errors", []).append(f"lag {lag} deg {deg}: {type(exc).__name__}: {exc}")
            continue
        best["seconds"] += fit.seconds
        if fit.r2_fr_val > best["fr_val"]:
            best.update(fr_val=fit.r2_fr_val, setting=fit.tool + (", u(t) offered" if direct else ""))
    return best


def run_suite(
    names: tuple[str, ...] | None = None,
    configs: dict[str, CoEAConfig] | None = None,
    seeds: tuple[int, ...] = tuple(range(SUITE_SEEDS)),
    peers: bool = False,
    quick: bool = False,
    progress: Callable[[str], object] | None = None,
    helper: EvalHelper | None = None,
) -> list[dict[str, Any]]:
    """Every target x config x seed (and the peers): one dict per target. ``helper``: the identifications use
    this started :class:`~streamid.engine.search.parallel.EvalHelper` (both cores, as ``streamid identify``; the
    results are the same with or without it, the seconds are not)."""
    cfgs = configs if configs is not None else {"paper": SUITE_PAPER, "default": DEFAULT}
    rows = []
    for t in targets(names):
        row: dict[str, Any] = {"target": t.name, "n_est": len(t.y_est), "n_val": len(t.y_val), "kind": t.kind}
        for label, cfg in cfgs.items():
            runs = [identify_target(t, cfg, s, helper) for s in seeds]
            fr = [r["fr_val"] for r in runs]
            row[label] = {"fr_val": fr, "median": statistics.median(fr), "min": min(fr),
                          "seconds": statistics.median(r["seconds"] for r in runs), "runs": runs}
        paper_median = row["paper"]["median"] if "paper" in row else None
        for label in cfgs:
            r = row[label]
            r["silent"] = (None if paper_median is None else
                           silent_failures(r["fr_val"], [x["band"] for x in r["runs"]], paper_median))
            if progress is not None:
                covs = [x["band"]["coverage"] for x in r["runs"] if x["band"] is not None]
                progress(f"{t.name} {label}: median {r['median']:.4f} min {r['min']:.4f} {r['seconds']:.2f} s"
                         + (f", 90 % band covers {statistics.median(covs):.2f} (median)" if covs else "")
                         + ("" if r["silent"] is None else f", {r['silent']} silent failure(s)"))
        if peers:
            row["frols"] = frols_best(t, quick)
            if progress is not None:
                progress(f"{t.name} frols: {row['frols']['fr_val']:.4f} ({row['frols']['setting']})")
        rows.append(row)
    return rows


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench --suite`` provider: per system, paper settings vs defaults (vs FROLS with --peers)."""
    import sys

    from benchmarks.kit import Measurement

    quick = bool(options.quick)
    names = QUICK_SYSTEMS if quick else None
    if options.systems:
        unknown = [s for s in options.systems if s not in SYSTEMS]
        if unknown:
            raise ValueError(f"--systems takes names among {', '.join(SYSTEMS)}; got {', '.join(map(repr, unknown))}")
        names = tuple(options.systems)
    seeds = tuple(options.seed + i for i in range(1 if quick else SUITE_SEEDS))
    cfgs = {"paper": SUITE_PAPER, "default": DEFAULT}
    if quick:  # a smoke run of the same code paths, not for quoting
        cfgs = {"paper": SUITE_PAPER.replace(generations=10),
                "default": DEFAULT.replace(generations=5)}
    # Both cores, as `streamid identify` uses them: an EvalHelper evaluates half of every search batch (the same
    # results; docs/engine-results.md, "The second core"). Where it is not supported the engine goes alone.
    with ExitStack() as stack:
        helper = stack.enter_context(EvalHelper()) if EvalHelper.supported() else None
        rows = run_suite(names, cfgs, seeds, peers=bool(options.peers), quick=quick,
                         progress=lambda s: print(f"[suite] {s}", file=sys.stderr, flush=True), helper=helper)
    cores = "both cores (an EvalHelper)" if helper is not None else "one core"
    for row in rows:
        for label in cfgs:
            r = row[label]
            judged = ("validated on another experiment" if row.get("kind") == "two-experiment"
                      else "validated on the record's second part")
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", f"FR R2 val, {label}", "",
                              tuple(r["fr_val"]), f"median and min over seeds; {judged}")
            case = f"{row['target']} ({row['n_est']}/{row['n_val']})"
            bands = [x["band"] for x in r["runs"] if x["band"] is not None]
            if bands:
                yield Measurement("suite", case, f"90 % band coverage, {label}", "", tuple(b["coverage"] for b in bands),
                                  f"share of the validation samples inside the free run's 90 % interval; "
                                  f"{len(bands)} of {len(r['runs'])} seeds' models carry one")
                yield Measurement("suite", case, f"band width / output std, {label}", "",
                                  tuple(b["width_over_std"] for b in bands), "mean width of the 90 % band")
                yield Measurement("suite", case, f"band width / FR RMS error, {label}", "",
                                  tuple(b["width_over_rms"] for b in bands), "issue 51: <= 4 where the model is good")
            if r.get("silent") is not None:
                yield Measurement("suite", case, f"silent failures, {label}", "", (float(r["silent"]),),
                                  f"seeds with FR R2 more than {SILENT_GAP} under the paper's median and a band "
                                  f"covering under {SILENT_COVERAGE:.0%} (of {len(r['runs'])})")
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", f"seconds, {label}", "s",
                              tuple(x["seconds"] for x in r["runs"]), f"wall per identification, {cores}")
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", f"networks, {label}", "",
                              tuple(float(x["networks"]) for x in r["runs"]), "in the kept model (> 1: a mean of runs)")
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", f"refined, {label}", "",
                              tuple(float(x["refined"]) for x in r["runs"]),
                              "1: the kept model's weights fitted to its free run (CoEAConfig.refine_iterations)")
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", f"long linear order, {label}",
                              "", tuple(float(x.get("long_linear", 0)) for x in r["runs"]),
                              "of the kept model's dense linear ARX part (0: none; CoEAConfig.long_linear)")
    for label in cfgs:
        counted = [row[label]["silent"] for row in rows
                   if row[label].get("silent") is not None and row.get("kind") == "two-experiment"]
        if counted:
            yield Measurement("suite", f"every two-experiment row ({len(counted)})", f"silent failures, {label}", "",
                              (float(sum(counted)),), "the sum over those rows and their seeds (issue 51's target: 0)")
    for row in rows:
        if "frols" in row:
            f = row["frols"]
            yield Measurement("suite", f"{row['target']} ({row['n_est']}/{row['n_val']})", "FR R2 val, FROLS best", "",
                              (float(f["fr_val"]),), f"{f['setting']}; grid fitted in {f['seconds']:.1f} s")
