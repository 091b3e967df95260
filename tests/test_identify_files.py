"""``streamid identify`` on a user's own file: delimiters, decimal comma, missing values, wrong columns, bundled names.

Real files written in tmp_path, read by the real command (``main()``, as ``python -m streamid`` runs it).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from streamid.commands.main import main
from streamid.logs.datafile import load_dataset

QUICK = ["--paper", "--neurons", "6", "--generations", "15", "--max-lag", "3", "--workers", "1", "--progress", "never"]


def signals(n: int = 400, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(3, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    return {"t_s": np.arange(n) * 0.01, "force": u, "noise": rng.uniform(0, 1, n), "pos": y}


def write(path: Path, cols: dict[str, np.ndarray], sep: str = ",", comma: bool = False,
          cells: dict[tuple[int, str], str] | None = None) -> Path:
    """A delimited file; ``cells[(row, column)]`` overrides a cell (row 0 = the first data row, file line 2)."""
    names = list(cols)
    lines = [sep.join(names)]
    for i in range(len(cols[names[0]])):
        row = []
        for c in names:
            text = repr(float(cols[c][i]))
            row.append(text.replace(".", ",") if comma else text)
        for (r, c), v in (cells or {}).items():
            if r == i:
                row[names.index(c)] = v
        lines.append(sep.join(row))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["identify", *args])
    out, err = capsys.readouterr()
    return code, out, err


def report(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[dict, str]:
    code, out, err = run(capsys, *args, *QUICK, "--json")
    assert code == 0, err
    return json.loads(out), err


def test_delimiters_and_decimal_comma_are_detected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same numbers as , ; tab | and whitespace files (; and tab with decimal commas) give the same model."""
    cols = signals()
    files = {
        "comma": write(tmp_path / "c.csv", cols),
        "semicolon": write(tmp_path / "s.csv", cols, ";", comma=True),
        "tab": write(tmp_path / "t.tsv", cols, "\t", comma=True),
        "pipe": write(tmp_path / "p.csv", cols, "|"),
        "whitespace": write(tmp_path / "w.csv", cols, "   "),
    }
    fitness = {}
    for name, path in files.items():
        rep, _ = report(capsys, str(path), "--input", "force", "--output", "pos")
        read = rep["data"]["read"]
        assert read["delimiter"] == name, read
        assert read["decimal"] == ("," if name in ("semicolon", "tab") else "."), read
        assert read["clock"] == "t_s" and rep["data"]["period_ns"] == 10_000_000, read
        fitness[name] = rep["runs"][0]["fitness"]
    assert len(set(fitness.values())) == 1, fitness  # every file read to the same numbers
    code, out, _ = run(capsys, str(files["semicolon"]), "--input", "force", "--output", "pos", *QUICK)
    assert code == 0 and "read      400 rows; semicolon-separated, decimal comma, clock 't_s' (period 10 ms)" in out


def test_delimiter_option_and_what_cannot_be_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cols = signals(100)
    tab = write(tmp_path / "t.csv", cols, "\t")
    rep, _ = report(capsys, str(tab), "--input", "force", "--output", "pos", "--delimiter", "tab")
    assert rep["data"]["read"]["delimiter"] == "tab"
    code, _, err = run(capsys, str(tab), "--input", "force", "--output", "pos", "--delimiter", ";", *QUICK)
    assert code == 2 and "gives one column with delimiter semicolon" in err and "--delimiter" in err, err
    code, _, err = run(capsys, str(tab), "--input", "force", "--output", "pos", "--delimiter", "colon", *QUICK)
    assert code == 2 and "--delimiter must be one of ',' ';' 'tab' '|' 'whitespace'" in err and "'colon'" in err, err
    one = tmp_path / "one.csv"
    one.write_text("force\n1\n2\n3\n")
    code, _, err = run(capsys, str(one), "--input", "force", "--output", "pos", *QUICK)
    assert code == 2 and "cannot tell the delimiter" in err and "--delimiter" in err, err
    quoted = write(tmp_path / "q.csv", cols, cells={(4, "force"): '"0,5"'})
    code, _, err = run(capsys, str(quoted), "--input", "force", "--output", "pos", *QUICK)
    assert code == 2 and "column 'force', line 6: '0,5' is not a number (a decimal comma?" in err, err
    bad_row = tmp_path / "r.csv"
    bad_row.write_text("a,b\n1,2\n3,4\n5\n6,7\n")
    code, _, err = run(capsys, str(bad_row), "--input", "a", "--output", "b", *QUICK)
    assert code == 2 and "line 4 has 1 fields; the header has 2 (delimiter comma)" in err, err


def test_missing_values_error_names_lines_and_the_two_ways_out(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    cols = signals()
    cells = {(9, "force"): "", (38, "pos"): "NaN", (39, "pos"): "NA", (39, "force"): "nan", (60, "noise"): ""}
    data = write(tmp_path / "m.csv", cols, cells=cells)
    code, _, err = run(capsys, str(data), "--input", "force", "--output", "pos", *QUICK)
    assert code == 2, err
    assert "3 rows of 400 have a missing value (empty, NaN, NA) in the columns used: line 11 (force); line 40 (pos); " \
           "line 41 (force, pos)." in err, err  # line 62: only the unused column 'noise' misses a value
    assert "--fill to fill them by linear interpolation" in err and "--drop to leave those rows out" in err

    rep, err = report(capsys, str(data), "--input", "force", "--output", "pos", "--fill")
    m = rep["data"]["read"]["missing"]
    assert m == {"policy": "fill", "rows_with_missing": 3, "rows_dropped": 0, "values_filled": 4,
                 "places_spacing_broken": 0}, m
    assert "warning: --fill: filled 4 missing values in 3 rows by linear interpolation" in err, err
    assert "longest run 2 samples: 'pos', line 40-41" in err, err
    assert rep["data"]["n_est"] + rep["data"]["n_val"] == 400
    ds = load_dataset(data, ["force"], "pos", missing="fill")
    u = cols["force"]
    assert ds.u_est[9, 0] == pytest.approx((u[8] + u[10]) / 2)  # line 11 = row 9, between its neighbours
    y = cols["pos"]
    assert ds.y_est[38] == pytest.approx(y[37] + (y[40] - y[37]) / 3) and ds.y_est[39] == pytest.approx(y[37] + 2 * (y[40] - y[37]) / 3)

    rep, err = report(capsys, str(data), "--input", "force", "--output", "pos", "--drop")
    m = rep["data"]["read"]["missing"]
    assert m["rows_dropped"] == 3 and m["places_spacing_broken"] == 2 and rep["data"]["n_est"] + rep["data"]["n_val"] == 397
    assert "--drop: left out 3 rows inside the record (line 11; line 40-41): the sample spacing is broken at 2 places" \
           in err, err

    with pytest.raises(SystemExit) as stop:
        run(capsys, str(data), "--input", "force", "--output", "pos", "--drop", "--fill", *QUICK)
    assert stop.value.code == 2 and "argument --fill: not allowed with argument --drop" in capsys.readouterr().err


def test_drop_refused_at_many_places_and_ends_cut(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cols = signals()
    holes = {(10 + 30 * k, "pos"): "" for k in range(5)}  # 5 places; 400 rows allow 4
    data = write(tmp_path / "h.csv", cols, cells=holes)
    code, _, err = run(capsys, str(data), "--input", "force", "--output", "pos", "--drop", *QUICK)
    assert code == 2 and "--drop would join samples that were not adjacent at 5 places" in err, err
    assert "(4 here)" in err and "Use --fill" in err
    ends = write(tmp_path / "e.csv", cols, cells={(0, "pos"): "", (1, "force"): "null", (399, "pos"): "N/A"})
    rep, err = report(capsys, str(ends), "--input", "force", "--output", "pos", "--drop")
    assert rep["data"]["read"]["missing"]["places_spacing_broken"] == 0
    assert rep["data"]["n_est"] == 198 and rep["data"]["n_val"] == 199
    assert "cut 2 rows at the start and 1 at the end of the record" in err and "spacing is kept" in err, err
    ds = load_dataset(ends, ["force"], "pos", missing="fill")
    assert ds.y_est[0] == cols["pos"][2] and ds.t_ns is not None and ds.t_ns[0] == 20_000_000  # the clock is cut too


def test_columns_a_model_cannot_be_made_of(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cols = signals(200)
    cols["copy"] = cols["pos"].copy()
    cols["flat"] = np.full(200, 3.5)
    data = write(tmp_path / "d.csv", cols)
    code, _, err = run(capsys, str(data), "--input", "pos", "--output", "pos", *QUICK)
    assert code == 2 and "--input pos: the column 'pos' is the --output too" in err, err
    code, _, err = run(capsys, str(data), "--input", "copy", "--output", "pos", *QUICK)
    assert code == 2 and "--input copy: the column 'copy' holds exactly the values of the output 'pos'" in err, err
    code, _, err = run(capsys, str(data), "--input", "flat", "--output", "pos", *QUICK)
    assert code == 2 and "--input flat: the column 'flat' is constant (every value 3.5)" in err, err
    code, _, err = run(capsys, str(data), "--input", "force", "--input", "force", "--output", "pos", *QUICK)
    assert code == 2 and "--input force is given twice" in err, err
    code, _, err = run(capsys, str(data), "--input", "t_s", "--output", "pos", *QUICK)
    assert code == 2, err
    assert "--input t_s: the column 't_s' is increasing over all its 200 samples (a time column?)" in err, err
    assert "pass --allow-time-input to use it anyway" in err
    rep, err = report(capsys, str(data), "--input", "force", "--input", "t_s", "--output", "pos", "--allow-time-input")
    assert "warning: --input t_s: the column 't_s' is increasing" in err and "(used, --allow-time-input)" in err, err
    assert rep["data"]["inputs"] == ["force", "t_s"] and len(rep["data"]["warnings"]) == 1
    down = tmp_path / "down.csv"
    write(down, {"countdown": 5.0 - np.arange(200) * 0.5, "force": cols["force"], "pos": cols["pos"]})
    code, _, err = run(capsys, str(down), "--input", "countdown", "--output", "pos", *QUICK)
    assert code == 2 and "the column 'countdown' is decreasing" in err, err


def test_bundled_log_by_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "mr_damper", "--est", "2000", *QUICK)  # the log's input and output by default
    assert code == 0, err
    assert "velocity_cm_s -> force_N" in out and "3499 rows; clock of the log (period 5 ms)" in out, out
    assert "streamid identify: " in out and "mr_damper.mcap" in out
    code, _, err = run(capsys, "mr_dampr", *QUICK)
    assert code == 2 and "DATA: 'mr_dampr' does not exist here" in err and "mr_damper" in err and "piezo_p885" in err
    assert "did you mean 'mr_damper'" in err, err
    code, _, err = run(capsys, str(tmp_path / "none.csv"), "--input", "u", "--output", "y", *QUICK)
    assert code == 2 and "does not exist" in err and "bundled log name" in err, err
    data = write(tmp_path / "d.csv", signals(50))
    code, _, err = run(capsys, str(data), *QUICK)
    assert code == 2 and "give --input COL" in err and "['force', 'noise', 'pos', 't_s']" in err, err
    code, _, err = run(capsys, "cstr", *QUICK)
    assert code == 2 and "has outputs" in err and "choose one with --output" in err, err


def test_mat_file_missing_values_are_named_by_sample(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A .mat file has no lines: rows are named by 1-based sample; it has no clock either, and says so."""
    from scipy.io import savemat

    cols = signals(300)
    u = cols["force"].copy()
    u[[4, 150]] = np.nan
    mat = tmp_path / "m.mat"
    savemat(mat, {"u": u, "y": cols["pos"]})
    code, _, err = run(capsys, str(mat), "--input", "u", "--output", "y", *QUICK)
    assert code == 2 and "2 rows of 300 have a missing value" in err and "sample 5 (u); sample 151 (u)." in err, err
    code, out, err = run(capsys, str(mat), "--input", "u", "--output", "y", "--fill", *QUICK)
    assert code == 0, err
    assert "read      300 rows; no clock (samples counted), 2 rows with missing values (fill: 0 rows left out, " \
           "2 values filled)" in out, out


def test_a_column_that_is_not_numbers_stops_the_file_only_when_it_is_used(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A notes column beside the signals (text in a cell) does not stop an identification of the others; used, it is
    an error naming its cell; a misspelt column is named as unknown, whatever else the file holds. A time column's
    fault always stops the file: it would be the samples' clock."""
    cols = signals(200)
    notes = write(tmp_path / "n.csv", cols, cells={(7, "noise"): "valve opened"})
    rep, _ = report(capsys, str(notes), "--input", "force", "--output", "pos")
    assert rep["data"]["n_est"] + rep["data"]["n_val"] == 200 and rep["data"]["read"]["clock"] == "t_s", rep["data"]
    code, _, err = run(capsys, str(notes), "--input", "noise", "--output", "pos", *QUICK)
    assert code == 2 and "column 'noise', line 9: 'valve opened' is not a number" in err, err
    code, _, err = run(capsys, str(notes), "--input", "force", "--output", "pso", *QUICK)
    assert code == 2 and "unknown column 'pso'" in err and "'pos'" in err, err
    clock = write(tmp_path / "c.csv", cols, cells={(3, "t_s"): "later"})
    code, _, err = run(capsys, str(clock), "--input", "force", "--output", "pos", *QUICK)
    assert code == 2 and "column 't_s', line 5: 'later' is not a number" in err, err
