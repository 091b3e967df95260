"""``streamid bench --suite --quick``: every system loads, the smoke run gives figures for each quick system."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from benchmarks import command
from benchmarks.suite import QUICK_SYSTEMS, SYSTEMS, free_run_val, targets


def test_every_system_of_the_suite_loads_with_its_split() -> None:
    want = {
        "ball_and_beam": (500, 500), "heat_exchanger": (2000, 2000), "robot_arm": (512, 512),
        "cstr:concentration_mol_l": (3750, 3750), "cstr:temperature_K": (3750, 3750),
        "f16_gvt:accel1_au": (8192, 8192), "mr_damper": (2000, 1499), "reactor": (480, 480),
        "bouc_wen [sweep]": (10_000, 153_000), "bouc_wen [multisine]": (10_000, 8192), "rlc [id->test]": (10_000, 10_000),
    }
    sims = ("piezo_sim", "mr_damper_sim", "bouc_wen_sim", "reactor_sim")
    got = {t.name: t for t in targets(tuple(n for n in SYSTEMS if n not in ("piezo_p885", *sims)))}
    for name, (n_est, n_val) in want.items():
        t = got[name]
        assert (len(t.y_est), len(t.y_val)) == (n_est, n_val), name
        assert t.u_est.shape == (n_est, 1) and np.all(np.isfinite(t.u_val)) and np.ptp(t.y_est) > 0
    assert sum(1 for n in got if n.startswith("f16_gvt:")) == 3 and got["f16_gvt:accel2_au"].periodic_val
    # The Bouc-Wen validation is the benchmark's sine sweep (40 N), not the estimation multisine.
    assert float(np.max(np.abs(got["bouc_wen [sweep]"].u_val))) == pytest.approx(40.0, abs=1e-6)
    assert got["bouc_wen [multisine]"].periodic_val and got["f16_gvt:accel1_au"].kind == "two-experiment"
    assert got["mr_damper"].kind == "half" and got["rlc [id->test]"].kind == "two-experiment"


def test_every_simulated_device_has_pairs_on_another_experiment() -> None:
    """Issue 37: each simulator estimated on one excitation and validated on another, two pairs inside the
    estimation range and one a step beyond it."""
    from benchmarks.experiments import PAIRS

    for system, load in PAIRS.items():
        pairs = load()
        assert len(pairs) == 3 and sum(p.beyond for p in pairs) == 1, system
        for p in pairs:
            assert p.u_est.shape[1] == 1 and np.all(np.isfinite(p.y_est)) and np.all(np.isfinite(p.y_val))
            assert not np.allclose(p.u_est[: len(p.u_val)], p.u_val[: len(p.u_est)])  # another excitation
            est_peak = float(np.max(np.abs(p.u_est - p.u_est.mean())))
            val_peak = float(np.max(np.abs(p.u_val - p.u_est.mean())))
            assert (val_peak > 1.1 * est_peak) == p.beyond, (system, p.label, est_peak, val_peak)


def test_periodic_validation_scores_the_second_pass() -> None:
    from streamid.engine import PAPER, identify

    t = targets(("reactor",))[0]
    model = identify(t.u_est, t.y_est, PAPER.replace(generations=10), 0).model
    periodic = type(t)(t.system, t.output, t.u_est, t.y_est, t.u_val, t.y_val, periodic_val=True)
    a, b = free_run_val(model, t), free_run_val(model, periodic)
    sim = model.simulate(np.concatenate([t.u_val, t.u_val]), t.y_val[: model.max_lag])[len(t.y_val) :]
    assert b == pytest.approx(1 - np.sum((t.y_val - sim) ** 2) / np.sum((t.y_val - t.y_val.mean()) ** 2))
    assert a != b
    # a linear part that makes the free run diverge scores -inf (was: r2 raised on the infinite values)
    from dataclasses import replace

    k = len(model.regressors)
    wild = replace(model, linear=np.r_[[5.0 if r.signal == "y" else 0.0 for r in model.regressors], 0.0])
    assert k >= 1 and free_run_val(wild, t) == float("-inf") and free_run_val(wild, periodic) == float("-inf")


def test_bench_suite_quick_runs_from_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    command.register(sub)
    args = parser.parse_args(["bench", "--suite", "--quick", "--json"])
    assert command.run(args) == 0  # (its time is the bench's figure, not a test's: no wall-clock bound here)
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["failures"] == []
    rows = doc["measurements"]
    assert {r["section"] for r in rows} == {"suite"}
    for system in QUICK_SYSTEMS:
        mine = [r for r in rows if r["case"].startswith(system)]
        assert {r["metric"] for r in mine} == {"FR R2 val, paper", "FR R2 val, default", "seconds, paper",
                                               "seconds, default", "networks, paper", "networks, default",
                                               "refined, paper", "refined, default", "long linear order, paper",
                                               "long linear order, default", "90 % band coverage, paper",
                                               "90 % band coverage, default", "band width / output std, paper",
                                               "band width / output std, default", "band width / FR RMS error, paper",
                                               "band width / FR RMS error, default", "silent failures, paper",
                                               "silent failures, default"}, system
        assert next(r for r in mine if r["metric"] == "long linear order, paper")["max"] == 0.0  # never with the paper's
        assert all(r["median"] >= 1 for r in mine if r["metric"].startswith("networks"))
        assert next(r for r in mine if r["metric"] == "refined, paper")["max"] == 0.0  # the paper never refines
        assert all(v in (0.0, 1.0) for r in mine if r["metric"].startswith("refined") for v in r["values"])
        assert all(np.isfinite(r["median"]) for r in mine)
        assert all(0.0 <= v <= 1.0 for r in mine if r["metric"].startswith("90 % band coverage") for v in r["values"])
        assert all(r["median"] > 0 for r in mine if r["metric"].startswith("band width"))
        assert all(r["values"] in ([0.0], [1.0]) for r in mine if r["metric"].startswith("silent"))  # of 1 seed
    notes = {r["case"].split(" (")[0]: r["note"] for r in rows if r["metric"] == "FR R2 val, default"}
    assert all(n.endswith("validated on the record's second part") for n in notes.values()), notes  # half/half rows
    # the silent failures' sum is over the two-experiment rows (the quick systems are half/half: none)
    assert not [r for r in rows if r["metric"].startswith("silent") and r["case"].startswith("every")]
    reactor = [r for r in rows if r["case"].startswith("reactor") and r["metric"] == "FR R2 val, default"]
    assert reactor[0]["median"] > 0.99  # even the smoke run identifies the reactor


def test_run_table_validates_every_run_and_marks_the_one_taken() -> None:
    from streamid.engine import DEFAULT, PAPER

    from benchmarks.suite import run_table

    t = targets(("reactor",))[0]
    # the choice as made: unrefined, and one run's network (no mean of networks, which the 5-generation runs can take)
    cfg = DEFAULT.replace(generations=5, refine_iterations=0, run_ensembles=False)
    table = run_table(t, cfg, 0)
    runs = table["runs"]
    assert len(runs) >= cfg.restarts and [r["run"] for r in runs] == list(range(len(runs)))
    assert [r["run"] for r in runs if r["chosen"]] == [table["chosen"]]
    assert runs[table["chosen"]]["fr_val"] == table["fr_val"]  # the model taken is the run's candidate
    assert all(np.isfinite(r["fr_val"]) and r["neurons"] >= 1 and r["lags"] for r in runs)
    ok = [r for r in runs if r["criterion"] is not None]
    assert ok and runs[table["chosen"]]["criterion"] == min(r["criterion"] for r in ok)
    with pytest.raises(ValueError, match="selection='fr_est' and restarts > 1"):
        run_table(t, PAPER.replace(generations=5), 0)


def test_bench_suite_systems_option_runs_a_two_experiment_system(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    command.register(sub)
    assert command.run(parser.parse_args(["bench", "--suite", "--quick", "--json", "--systems", "reactor_sim"])) == 0
    rows = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["measurements"]
    fr = [r for r in rows if r["metric"] == "FR R2 val, default"]
    assert len(fr) == 3 and all(r["case"].startswith("reactor_sim [") for r in fr), [r["case"] for r in fr]
    assert all(r["note"].endswith("validated on another experiment") for r in fr)
    assert sum("beyond" in r["case"] for r in fr) == 1
    from streamid.errors import ConfigError

    with pytest.raises(ConfigError, match="--systems takes names among piezo_sim, .*; got 'nope'"):
        command.run(parser.parse_args(["bench", "--suite", "--systems", "reactor_sim,nope"]))
    with pytest.raises(ConfigError, match="add --suite"):
        command.run(parser.parse_args(["bench", "--systems", "reactor_sim"]))


def test_silent_failures_need_a_poor_free_run_and_a_band_that_does_not_say_so() -> None:
    from benchmarks.suite import SILENT_COVERAGE, SILENT_GAP, silent_failures

    paper_median = 0.9
    poor, fine = paper_median - SILENT_GAP - 0.01, paper_median - SILENT_GAP + 0.01
    said = {"coverage": SILENT_COVERAGE - 0.1}  # a band that misses the data: the model does not say it is wrong
    wide = {"coverage": SILENT_COVERAGE + 0.1}  # a band wide enough to cover: it says so
    assert silent_failures([poor], [said], paper_median) == 1
    assert silent_failures([poor], [wide], paper_median) == 0
    assert silent_failures([poor], [None], paper_median) == 1  # no interval says nothing
    assert silent_failures([fine], [said], paper_median) == 0  # good enough: not a failure
    assert silent_failures([poor, fine, poor], [said, said, wide], paper_median) == 1
