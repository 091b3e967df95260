"""Data files read by Apache Arrow (issue 53, items 3 and 6): CSV, Parquet and Arrow IPC (Feather) into float64
columns, only the columns named, bounded memory; bad input still one line naming the row and column, exit 2."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
import pytest
from conftest import STREAMID

import streamid.logs.csv_table as csv_table
from benchmarks.reading import measure_read, write_digits_csv
from streamid.errors import DataError
from streamid.logs.datafile import load_dataset, load_table


def _signals(n: int = 300) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    return {"time_s": np.arange(n) * 0.01, "u": rng.uniform(-1, 1, n), "note": rng.normal(size=n),
            "y": rng.normal(size=n)}


def _csv(path: Path, cols: dict[str, np.ndarray], sep: str = ",", comma: bool = False, enc: str = "utf-8") -> Path:
    rows = [sep.join(cols)] + [sep.join(repr(float(cols[c][i])).replace(".", "," if comma else ".") for c in cols)
                               for i in range(len(cols["u"]))]
    path.write_bytes(("\n".join(rows) + "\n").encode(enc))
    return path


@pytest.mark.parametrize(("sep", "comma", "enc"), [(",", False, "utf-8"), (";", True, "utf-8"), ("\t", True, "utf-8"),
                                                   ("|", False, "utf-8"), ("   ", False, "utf-8"),
                                                   (",", False, "utf-16"), (",", False, "utf-8-sig")])
def test_csv_dialects_are_read_by_arrow_to_the_same_numbers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           sep: str, comma: bool, enc: str) -> None:
    """Every dialect the detection accepts goes through Arrow (the line-by-line reader is never called), the
    named columns and the time column only, to exactly the numbers Python's float() reads."""
    cols = _signals()
    path = _csv(tmp_path / "d.csv", cols, sep, comma, enc)

    def refused(*_: object) -> None:
        raise AssertionError("the line-by-line reader was used")

    monkeypatch.setattr(csv_table, "_python_read", refused)
    t = load_table(path, columns=["u", "y"])
    assert sorted(t.columns) == ["time_s", "u", "y"] and t.meta["columns"] == list(cols)  # 'note' not read
    assert all(np.array_equal(t.columns[c], cols[c]) for c in t.columns)
    assert t.meta["clock"] == "time_s" and t.period_ns == 10_000_000 and t.meta["decimal"] == ("," if comma else ".")


def test_blank_lines_and_missing_cells_keep_their_file_lines(tmp_path: Path) -> None:
    text = "\n# t_s,u,y\n0,1,2\n\n0.01,NA,3\n0.02,2, null \n\n\n0.03,5,None\n0.04,6,7\n"
    p = tmp_path / "b.csv"
    p.write_text(text)
    with pytest.raises(DataError, match=r"line 5 \(u\); line 6 \(y\); line 9 \(y\)"):
        load_dataset(p, ["u"], "y")
    ds = load_dataset(p, ["u"], "y", missing="fill", est=2)
    assert ds.u_est[:, 0].tolist() == [1.0, 1.5] and ds.u_val[:, 0].tolist() == [2.0, 5.0, 6.0]
    assert ds.y_val == pytest.approx([13 / 3, 17 / 3, 7.0])


def test_parquet_and_feather_read_like_the_csv(tmp_path: Path) -> None:
    cols = _signals()
    ref = load_table(_csv(tmp_path / "d.csv", cols), columns=["u", "y"])
    table = pa.table({**cols, "label": pa.array(["x"] * len(cols["u"]))})
    pq.write_table(table, tmp_path / "d.parquet", row_group_size=64)
    feather.write_feather(table, tmp_path / "d.feather", chunksize=50)
    with pa.OSFile(str(tmp_path / "d.arrows"), "wb") as sink, pa.ipc.new_stream(sink, table.schema) as w:
        w.write_table(table, max_chunksize=70)  # the IPC stream format, under an IPC extension below
    (tmp_path / "d.arrows").rename(tmp_path / "s.arrow")
    for name in ("d.parquet", "d.feather", "s.arrow"):
        t = load_table(tmp_path / name, columns=["u", "y"])
        assert sorted(t.columns) == ["time_s", "u", "y"], name
        assert all(np.array_equal(t.columns[c], ref.columns[c]) for c in t.columns), name
        assert t.meta["clock"] == "time_s" and np.array_equal(t.t_ns, ref.t_ns) and t.period_ns == ref.period_ns
        with pytest.raises(DataError, match=r"column 'label' holds string values, not numbers"):
            t.column("label")
        with pytest.raises(DataError, match=r"unknown column 'yy' in .*; available columns: \['label', 'note', "):
            t.column("yy")
    ds = load_dataset(tmp_path / "d.parquet", ["u"], "y", est=100)
    assert ds.n_est == 100 and ds.info["clock"] == "time_s" and np.array_equal(ds.y_val, cols["y"][100:])


def test_parquet_nulls_integers_and_a_timestamp_clock(tmp_path: Path) -> None:
    n = 50
    stamps = pa.array(np.datetime64("2026-01-01T00:00:00") + np.arange(n) * np.timedelta64(2, "ms"))
    u = pa.array([None if i == 7 else i % 5 for i in range(n)], type=pa.int32())
    pq.write_table(pa.table({"stamp": stamps, "u": u, "y": np.arange(n) * 0.5}), tmp_path / "t.parquet")
    t = load_table(tmp_path / "t.parquet")
    assert t.meta["clock"] == "stamp" and t.period_ns == 2_000_000 and np.isnan(t.columns["u"][7])
    assert t.columns["u"][8] == 3.0 and t.columns["u"].dtype == np.float64
    with pytest.raises(DataError, match=r"1 row of 50 has a missing value .* sample 8 \(u\)"):
        load_dataset(tmp_path / "t.parquet", ["u"], "y")


def _one_line_exit_2(args: list[str]) -> str:
    r = subprocess.run([*STREAMID, *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_bad_files_are_one_line_errors_naming_the_row_and_column(tmp_path: Path) -> None:
    cases = {
        "ragged.csv": ("t,u,y\n0,1,2\n1,2,3\n2,3\n3,4,5\n", "line 4 has 2 fields; the header has 3"),
        "text.csv": ("t,u,y\n0,1,2\n1,2,3\n2,x7,3\n", "column 'u', line 4: 'x7' is not a number"),
        "empty.csv": ("", "a CSV file needs a header row with column names and at least one data row"),
        "header.csv": ("t,u,y\n\n", "a CSV file needs a header row"),
        "columns.csv": ("t,u,yy\n0,1,2\n1,2,3\n", "unknown column 'y' in"),
    }
    for name, (text, says) in cases.items():
        (tmp_path / name).write_text(text)
        line = _one_line_exit_2(["identify", str(tmp_path / name), "--input", "u", "--output", "y"])
        assert says in line and name in line, line
    (tmp_path / "cut.parquet").write_bytes(b"PAR1" + bytes(100))
    line = _one_line_exit_2(["identify", str(tmp_path / "cut.parquet"), "--input", "u", "--output", "y"])
    assert "cut.parquet: not a readable Parquet file" in line, line
    pq.write_table(pa.table({"u": [1.0, 2.0, 3.0], "y": [3.0, 1.0, 2.0]}), tmp_path / "p.parquet")
    line = _one_line_exit_2(["identify", str(tmp_path / "p.parquet"), "--input", "u", "--output", "z"])
    assert "unknown column 'z'" in line and "['u', 'y']" in line, line


def test_the_5m_row_csv_takes_under_twice_its_float64_columns(tmp_path: Path) -> None:
    """Issue 53's 20 MB CSV of 5,000,000 rows (was: 1.68 GB peak, 84 x the file): read in a fresh process, its peak
    RSS over the RSS before the read (imports done) is under 2 x the float64 columns returned (a bound in bytes)."""
    path = tmp_path / "digits.csv"
    assert write_digits_csv(path) == 20_000_004
    got = measure_read(path, ["u", "y"])
    assert got["rows"] == 5_000_000 and got["numeric_mib"] == pytest.approx(5_000_000 * 2 * 8 / 2**20)
    assert got["rss_over_start_mib"] < 2 * got["numeric_mib"], got


def test_identify_shows_the_reading_stage_and_is_quiet_under_never(tmp_path: Path) -> None:
    """`--progress always` draws a "read" bar (rows read) before the identification's; `never` draws nothing."""
    path = _csv(tmp_path / "d.csv", _signals(400))
    quick = ["--neurons", "4", "--generations", "4", "--max-lag", "2", "--workers", "1", "--json"]
    shown = subprocess.run([*STREAMID, "identify", str(path), "--input", "u", "--output", "y", *quick,
                            "--progress", "always"], capture_output=True, timeout=120)
    err = shown.stderr.decode()
    assert shown.returncode == 0, err
    assert "\rread [##############################] 100.0% 400 rows" in err and err.index("\rread") < err.index("\ridentify")
    quiet = subprocess.run([*STREAMID, "identify", str(path), "--input", "u", "--output", "y", *quick,
                            "--progress", "never"], capture_output=True, timeout=120)
    assert quiet.returncode == 0 and "\r" not in quiet.stderr.decode(), quiet.stderr
