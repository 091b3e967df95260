"""``streamid identify`` end to end: real files (CSV, MAT, MCAP), real subprocesses, real reports."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from streamid.commands.identify_io import Bar as _Bar
from streamid.model import Model
from streamid.engine.validation import prediction_r2

STREAMID = [sys.executable, "-m", "streamid"]
DATA = Path(__file__).parent / "data"
QUICK = ["--paper", "--neurons", "6", "--generations", "20", "--max-lag", "3", "--workers", "1", "--progress", "never"]


def narx_csv(path: Path, n: int = 600, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    w = rng.uniform(0, 1, n)  # an input the output does not depend on
    y = np.zeros(n)
    for t in range(3, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    t_s = np.arange(n) * 0.01
    np.savetxt(path, np.column_stack([t_s, u, w, y]), delimiter=",", header="t_s,force,noise,pos", comments="", fmt="%.12g")


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, "identify", *args], capture_output=True, text=True, timeout=timeout)


def test_csv_report_and_model(tmp_path: Path) -> None:
    data = tmp_path / "d.csv"
    narx_csv(data)
    rep, mod = tmp_path / "r.json", tmp_path / "m.json"
    p = cli(str(data), "--input", "force", "--output", "pos", *QUICK, "--report", str(rep), "--model", str(mod))
    assert p.returncode == 0, p.stderr
    assert "force -> pos" in p.stdout and "estimation 300 samples" in p.stdout and "validation 300" in p.stdout
    r = json.loads(rep.read_text())
    assert r["best"] == 0 and len(r["runs"]) == 1
    run = r["runs"][0]
    assert set(run) >= {"seed", "seconds", "evaluations", "fitness", "lags", "r2", "correlation"}
    assert 1 in run["lags"]["y"] and 2 in run["lags"]["u"][0]
    assert run["evaluations"] == 20 * 22
    assert set(run["r2"]) == {"osa_est", "osa_val", "fr_est", "fr_val"}
    assert set(run["correlation"]) == {"est", "val"} and "ee" in run["correlation"]["val"]["tests"]
    assert set(r["summary"]["fitness"]) >= {"min", "max", "mean", "std"}
    m = Model.from_json(mod.read_text())
    assert m.lags == run["lags"]
    assert f"pos(t) = F[{m.lags_text()}]" in p.stdout and m.lags_text().startswith("pos(t-1")
    assert m.input_names == ("force",) and m.output_name == "pos"
    assert m.window["n_samples"] == 300 and m.window["source"] == "d.csv"
    raw = np.loadtxt(data, delimiter=",", skiprows=1)
    osa, fr, _ = prediction_r2(m, raw[300:, 1], raw[300:, 3])
    assert osa == pytest.approx(run["r2"]["osa_val"], rel=1e-12) and fr == pytest.approx(run["r2"]["fr_val"], rel=1e-12)


def test_runs_in_parallel_give_table4_statistics(tmp_path: Path) -> None:
    data = tmp_path / "d.csv"
    narx_csv(data, n=400)
    rep = tmp_path / "r.json"
    args = [str(data), "--input", "force", "--input", "noise", "--output", "pos", "--est-fraction", "0.6"]
    p = cli(*args, *QUICK[:-4], "--runs", "3", "--seed", "7", "--workers", "2", "--progress", "never", "--report", str(rep))
    assert p.returncode == 0, p.stderr
    r = json.loads(rep.read_text())
    assert [x["seed"] for x in r["runs"]] == [7, 8, 9]
    f = [x["fitness"] for x in r["runs"]]
    s = r["summary"]["fitness"]
    assert s["min"] == min(f) and s["max"] == max(f) and s["mean"] == pytest.approx(np.mean(f))
    assert s["std"] == pytest.approx(np.std(f, ddof=1))
    assert r["best"] == int(np.argmin(f))  # --paper: chosen by fitness
    assert "min" in p.stdout and "Table 4" in p.stdout
    assert all(len(x["lags"]["u"]) == 2 for x in r["runs"])
    # the same seeds in one process give the same numbers
    rep1 = tmp_path / "r1.json"
    p1 = cli(*args, *QUICK, "--runs", "3", "--seed", "7", "--report", str(rep1))
    assert p1.returncode == 0, p1.stderr
    assert [x["fitness"] for x in json.loads(rep1.read_text())["runs"]] == f


def test_mat_file(tmp_path: Path) -> None:
    p = cli(str(DATA / "mr_damper" / "Magneto.mat"), "--input", "U", "--output", "Y", "--est", "1400", *QUICK)
    assert p.returncode == 0, p.stderr
    assert "estimation 1400 samples" in p.stdout and "validation 600" in p.stdout


def test_mcap_log() -> None:
    from streamid.logs import bundled_log

    p = cli(str(bundled_log("mr_damper")), "--input", "velocity_cm_s", "--output", "force_N", "--est", "2000", *QUICK)
    assert p.returncode == 0, p.stderr
    assert "velocity_cm_s -> force_N" in p.stdout and "validation 1499" in p.stdout


def test_unknown_column_and_bad_values(tmp_path: Path) -> None:
    data = tmp_path / "d.csv"
    narx_csv(data, n=100)
    p = cli(str(data), "--input", "forse", "--output", "pos", *QUICK)
    assert p.returncode == 2
    assert "unknown column 'forse'" in p.stderr and "'force'" in p.stderr
    text = data.read_text().splitlines()
    text[10] = text[10].replace(text[10].split(",")[1], "nan", 1)
    data.write_text("\n".join(text) + "\n")
    p = cli(str(data), "--input", "force", "--output", "pos", *QUICK)
    assert p.returncode == 2 and "1 row of 100 has a missing value" in p.stderr and "line 11 (force)" in p.stderr
    assert "--fill" in p.stderr and "--drop" in p.stderr
    text[12] = text[12].replace(text[12].split(",")[3], "abc", 1)
    data.write_text("\n".join(text) + "\n")
    p = cli(str(data), "--input", "force", "--output", "pos", *QUICK)
    assert p.returncode == 2 and "'abc' is not a number" in p.stderr and "column 'pos', line 13" in p.stderr


def test_bad_options() -> None:
    p = cli(str(DATA / "mr_damper" / "Magneto.mat"), "--input", "U", "--output", "Y", "--est-fraction", "1.5", *QUICK)
    assert p.returncode == 2 and "fraction must be in (0, 1)" in p.stderr
    p = cli(str(DATA / "mr_damper" / "Magneto.mat"), "--input", "U", "--output", "Y", *QUICK, "--neurons", "0")
    assert p.returncode == 2 and "neurons must be an integer" in p.stderr
    p = cli("/nonexistent.csv", "--input", "U", "--output", "Y", *QUICK)
    assert p.returncode == 2 and "does not exist" in p.stderr


def test_progress_bar_draws_after_its_delay() -> None:
    out = io.StringIO()
    bar = _Bar(out, True, "identify")
    bar.update(1, 10)
    assert out.getvalue() == ""  # nothing during the first second
    bar.t0 -= 2.0
    bar.update(5, 10, "generation 5/10")
    bar.close()
    text = out.getvalue()
    assert "\ridentify [" in text and " 50.0% generation 5/10" in text and text.endswith("\n")
    silent = io.StringIO()
    off = _Bar(silent, False, "x")
    off.t0 -= 2.0
    off.update(5, 10)
    off.close()
    assert silent.getvalue() == ""


def test_max_lag_y_and_u_json_line_and_every_test_explained(tmp_path: Path) -> None:
    """--max-lag-y/--max-lag-u bound the lags; --json is one JSON line on stdout (as on every command)."""
    data = tmp_path / "d.csv"
    narx_csv(data, n=400)
    base = [str(data), "--input", "force", "--output", "pos", *QUICK[:5], "--workers", "1", "--progress", "never"]
    p = cli(*base, "--max-lag-y", "1", "--max-lag-u", "2", "--json")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 1, p.stdout
    rep = json.loads(lines[0])
    assert rep["config"]["max_lag_y"] == 1 and rep["config"]["max_lag_u"] == 2
    assert max(rep["runs"][0]["lags"]["y"], default=0) <= 1 and max(rep["runs"][0]["lags"]["u"][0], default=0) <= 2
    t = cli(*base, "--max-lag-y", "1", "--max-lag-u", "2")
    assert t.returncode == 0, t.stderr
    assert "max lag y 1 / u 2" in t.stdout
    for name in ("ee", "ue", "e_eu", "u2_e", "u2_e2"):  # one line per test, with its verdict and the reason of a failure
        assert any(line.strip().startswith(f"{name} pass (") or line.strip().startswith(f"{name} FAIL: ")
                   for line in t.stdout.splitlines()), name
    for line in t.stdout.splitlines():
        if " FAIL: " in line:
            assert "lag" in line and "outside ±" in line, line
    bad = cli(*base, "--max-lag-y", "-1")
    assert bad.returncode == 2 and "max_lag_y" in bad.stderr and "-1" in bad.stderr, bad.stderr
