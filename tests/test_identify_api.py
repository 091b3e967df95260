"""identify(): restarts in worker processes, selection rules; dataset loading from CSV, MAT and MCAP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from streamid.logs.datafile import load_dataset, load_table, split_index
from streamid.engine import CoEAConfig
from streamid.engine.identification import free_run_r2, identify
from streamid.errors import ConfigError, DataError

DATA = Path(__file__).parent / "data"
SMALL = CoEAConfig(neurons=6, max_lag_y=3, max_lag_u=3, generations=12)


def narx(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(3, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    return u, y


def test_worker_processes_give_the_same_result_as_in_process() -> None:
    u, y = narx(300, 0)
    cfg = SMALL.replace(restarts=2, selection="fr_est")
    here = identify(u, y, cfg, 3, workers=1)
    there = identify(u, y, cfg, 3, workers=2)  # spawned processes
    a, b = here.model.to_dict(), there.model.to_dict()
    assert "workers" not in a["config"]  # how the runs were made is not a setting of the method
    assert a == b
    with pytest.raises(ConfigError, match=r"workers must be an integer in \[1, 1024\].*got 0"):
        identify(u, y, cfg, 3, workers=0)
    assert [r.seed for r in here.runs] == [r.seed for r in there.runs]


def test_selection_rules() -> None:
    u, y = narx(400, 1)
    fit = identify(u, y, SMALL.replace(restarts=3, selection="fitness"), 0)
    assert fit.chosen == int(np.argmin([r.fitness for r in fit.runs]))
    fr = identify(u, y, SMALL.replace(restarts=3, selection="fr_est"), 0)
    # the chosen model's free-run R^2 on the estimation data is its selection score
    score = free_run_r2([fr.model], u[:, None], y)[0]
    assert score == pytest.approx(fr.model.metrics["selection_score"], rel=1e-12)


def test_paper_mode_reports_progress_every_generation() -> None:
    u, y = narx(200, 3)
    seen: list[int] = []
    res = identify(u, y, SMALL, 0, callback=lambda p: seen.append(p.generation))
    assert seen == list(range(1, 13))
    assert len(res.fitness_history) == 12 and res.evaluations == 20 * 14


def test_load_csv_mat_mcap(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("a,b,c\n1,2,3\n4,5,6\n7,8,9.5\n")
    t = load_table(p)
    assert list(t.columns) == ["a", "b", "c"] and t.columns["c"].tolist() == [3.0, 6.0, 9.5]
    ds = load_dataset(p, ["a", "b"], "c", est=2)
    assert ds.u_est.shape == (2, 2) and ds.u_val.tolist() == [[7.0, 8.0]]
    with pytest.raises(DataError, match=r"unknown column 'd'.*\['a', 'b', 'c'\]"):
        load_dataset(p, ["d"], "c")
    mat = load_table(DATA / "mr_damper" / "Magneto.mat")
    assert {"U", "Y", "U_val", "Y_val"} <= set(mat.columns) and len(mat.columns["U"]) == 2000
    from streamid.logs import bundled_log

    log = load_dataset(bundled_log("mr_damper"), ["velocity_cm_s"], "force_N", est=2000)
    assert log.n_est == 2000 and log.n_val == 1499
    np.testing.assert_array_equal(log.u_est[:, 0], mat.columns["U"])  # the log holds the same samples
    np.testing.assert_array_equal(log.y_val, mat.columns["Y_val"])
    assert log.window()["t1_ns"] == 1999 * 5_000_000


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="does not exist"):
        load_table(tmp_path / "none.csv")
    (tmp_path / "x.txt").write_text("a\n1\n")
    with pytest.raises(DataError, match="unknown data format 'txt'"):
        load_table(tmp_path / "x.txt")
    (tmp_path / "h.csv").write_text("a,a\n1,2\n")
    with pytest.raises(DataError, match="distinct"):
        load_table(tmp_path / "h.csv")
    (tmp_path / "r.csv").write_text("a,b\n1,2\n3\n")
    with pytest.raises(DataError, match="line 3 has 1 fields"):
        load_table(tmp_path / "r.csv")
    (tmp_path / "m.mat").write_bytes(b"garbage" * 20)
    with pytest.raises(DataError, match="not a readable MATLAB"):
        load_table(tmp_path / "m.mat")
    (tmp_path / "l.csv").write_text("a,b\n1,2\n3,4\n5,6\n")
    with pytest.raises(DataError, match="different lengths"):
        from scipy.io import savemat

        savemat(tmp_path / "l.mat", {"a": np.arange(5.0), "b": np.arange(4.0)})
        load_dataset(tmp_path / "l.mat", ["a"], "b")


def test_split_index() -> None:
    assert split_index(10) == 5
    assert split_index(10, est=3) == 3
    assert split_index(10, est_fraction=0.7) == 7
    with pytest.raises(DataError, match=r"integer in \[1, 9\]"):
        split_index(10, est=10)
    with pytest.raises(DataError, match="not both"):
        split_index(10, est=3, est_fraction=0.5)


def test_a_validation_file_is_the_validation_data(tmp_path: Path) -> None:
    """load_dataset(..., validation=FILE): all of the data file is estimation data, the second file validation."""
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("t_s,x,z\n0,1,2\n0.5,2,3\n1,4,5\n1.5,3,1\n")
    b.write_text("t_s;x;z\n7,5;9;8\n8;7;6\n")  # another delimiter and decimal mark: each file is read as it is
    ds = load_dataset(a, ["x"], "z", validation=b)
    assert ds.n_est == 4 and ds.n_val == 2 and ds.validation_path == str(b)
    assert ds.u_est[:, 0].tolist() == [1, 2, 4, 3] and ds.y_val.tolist() == [8, 6]
    assert ds.t_ns is not None and ds.t_ns.tolist() == [0, 500_000_000, 1_000_000_000, 1_500_000_000,
                                                        2_000_000_000, 2_500_000_000]  # drawn after the estimation
    assert ds.window()["period_ns"] == 500_000_000 and ds.info["validation"]["delimiter"] == "semicolon" and ds.info["validation"]["decimal"] == ","
    assert not any("validation file is the data file" in n for n in ds.notes)
    itself = load_dataset(a, ["x"], "z", validation=tmp_path / "." / "a.csv")
    assert any(n.startswith("the validation file is the data file") for n in itself.notes), itself.notes
    with pytest.raises(DataError, match="give one or the other"):
        load_dataset(a, ["x"], "z", validation=b, est=2)
    c = tmp_path / "c.csv"
    c.write_text("t_s,x,z\n0,1,2\n2,2,3\n4,4,5\n")
    with pytest.raises(DataError, match=r"samples every 2000 ms but .*a\.csv every 500 ms"):
        load_dataset(a, ["x"], "z", validation=c)
    d = tmp_path / "d.csv"
    d.write_text("t_s,x,y\n0,1,2\n0.5,2,3\n")
    with pytest.raises(DataError, match=r"unknown column 'z' in .*d\.csv"):
        load_dataset(a, ["x"], "z", validation=d)


def test_retired_fields_are_refused_with_the_reason() -> None:
    from streamid.engine import DEFAULT, CoEAConfig
    from streamid.errors import ConfigError

    with pytest.raises(ConfigError, match=r"\['agree_tol'\] were retired in issue 37 .*remove them"):
        CoEAConfig.from_dict({**DEFAULT.to_dict(), "agree_tol": 0.01})
    with pytest.raises(ConfigError, match=r"selection must be one of \['fr_est', 'fitness'\]; got 'holdout_fr'"):
        CoEAConfig(selection="holdout_fr")


def test_harmony_stop_is_a_constant_of_the_method_and_an_argument_of_one_run() -> None:
    from streamid.engine import DEFAULT, CoEAConfig, Coevolution
    from streamid.engine.settings import HARMONY_STOP
    from streamid.errors import ConfigError

    with pytest.raises(ConfigError, match=r"CoEAConfig\.harmony_stop was retired in issue 37: use the constant "
                                          r"streamid\.engine\.settings\.HARMONY_STOP \(0\.5, the paper's"):
        CoEAConfig.from_dict({**DEFAULT.to_dict(), "harmony_stop": 0.5})
    rng = np.random.default_rng(0)
    u = rng.standard_normal(200)
    y = np.convolve(u, [0.0, 0.5, 0.3])[:200]
    cfg = CoEAConfig(neurons=3, max_lag_y=2, max_lag_u=2, generations=10)
    assert HARMONY_STOP == 0.5 and Coevolution(u, y, cfg, 0).stop == 5  # the paper's: lags evolve half the run
    assert Coevolution(u, y, cfg, 0, harmony_stop=1.0).stop == 10  # a lag stage: throughout
    with pytest.raises(ConfigError, match=r"harmony_stop must be a fraction of the generations in \[0, 1\]; got 1\.5"):
        Coevolution(u, y, cfg, 0, harmony_stop=1.5)


def test_the_harmony_rates_are_the_papers_constants_and_arguments_of_one_run() -> None:
    from streamid.engine import DEFAULT, CoEAConfig, Coevolution
    from streamid.engine.settings import HMCR, PAR
    from streamid.errors import ConfigError

    assert HMCR == (0.8, 1.0) and PAR == (0.1, 0.9)  # the paper's Table 3
    for name, const in (("hmcr0", "HMCR"), ("hmcrf", "HMCR"), ("par0", "PAR"), ("parf", "PAR")):
        with pytest.raises(ConfigError, match=rf"CoEAConfig\.{name} was retired in issue 37: use the constant "
                                              rf"streamid\.engine\.settings\.{const} \("):
            CoEAConfig.from_dict({**DEFAULT.to_dict(), name: 0.5})
    rng = np.random.default_rng(0)
    u = rng.standard_normal(300)
    y = np.tanh(np.convolve(u, [0.0, 0.5, 0.3])[:300])
    cfg = CoEAConfig(neurons=3, max_lag_y=3, max_lag_u=3, generations=20)
    paper = Coevolution(u, y, cfg, 4).solve()
    same = Coevolution(u, y, cfg, 4, hmcr=(0.8, 1.0), par=(0.1, 0.9)).solve()
    other = Coevolution(u, y, cfg, 4, hmcr=(0.0, 0.0), par=(0.0, 0.0)).solve()  # every bit a coin flip
    assert paper.best_f == same.best_f and np.array_equal(paper.H, same.H) and np.array_equal(paper.X, same.X)
    assert not np.array_equal(other.H, paper.H)  # the rates do reach the search
    with pytest.raises(ConfigError, match=r"hmcr must be a pair \(first, last\) of rates in \[0, 1\]; got \(0\.8, 1\.2\)"):
        Coevolution(u, y, cfg, 0, hmcr=(0.8, 1.2))
    with pytest.raises(ConfigError, match=r"par must be a pair \(first, last\) of rates in \[0, 1\]; got 0\.5"):
        Coevolution(u, y, cfg, 0, par=0.5)  # type: ignore[arg-type]
