"""Models and data files from elsewhere, read by the real commands (issue 39, item 2).

Each hostile file is written for real and given to a real ``streamid`` process: every error is one
line on standard error, exit status 2, no traceback, and nothing is allocated beyond the stated
bounds (:mod:`streamid.model.limits`, :data:`streamid.logs.csv_table.MAX_LINE_CHARS`).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import STREAMID

from streamid.model import Model
from streamid.model.limits import MAX_DEPTH, MAX_LAG, MAX_MODEL_BYTES, MAX_NEURONS, MAX_PARAMETERS
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import DataError, ModelFormatError
from streamid.logs.csv_table import MAX_LINE_CHARS
from streamid.logs.datafile import load_table


def _doc(neurons: int, *, regressors: int = 1, width: float = 0.5, lag: int = 1) -> dict[str, Any]:
    return {"format": "streamid.model/1", "inputs": ["u"], "output": "y",
            "regressors": [{"signal": "y", "index": 0, "lag": lag}] + [{"signal": "u", "index": 0, "lag": 1 + i}
                                                                       for i in range(regressors - 1)],
            "centres": [[0.0] * regressors] * neurons, "widths": [width] * neurons, "weights": [0.1] * neurons,
            "normalisation": {"u_low": [-1.0], "u_high": [1.0], "y_low": -1.0, "y_high": 1.0}}


def _record(path: Path) -> Path:
    t = np.arange(400) * 0.01
    u = np.sin(3 * t)
    y = np.convolve(u, [0.5, 0.3], "same")
    np.savetxt(path, np.c_[t, u, y], delimiter=",", header="t,u,y", comments="")
    return path


def _max_rss_mb(args: list[str]) -> tuple[subprocess.CompletedProcess[str], float]:
    """Run ``args`` from a fresh wrapper process whose only child it is: its result and its peak RSS (MB)."""
    code = ("import resource, subprocess, sys, json; r = subprocess.run(json.loads(sys.argv[1]), capture_output=True, "
            "text=True); print(json.dumps([r.returncode, r.stdout, r.stderr, "
            "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024]))")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(args)], capture_output=True, text=True, timeout=300)
    rc, so, se, mb = json.loads(out.stdout)
    return subprocess.CompletedProcess(args, rc, so, se), mb


def _one_line_exit_2(r: subprocess.CompletedProcess[str]) -> str:
    assert r.returncode == 2, (r.returncode, r.stderr[-3000:])
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr[-3000:]
    return lines[0]


@pytest.mark.parametrize(("make", "says"), [
    (lambda: _doc(100_000), f"holds 100000 neurons; a model has at most {MAX_NEURONS}"),
    (lambda: _doc(1_000_000), f"(a model document is at most {MAX_MODEL_BYTES} bytes"),
    (lambda: "[" * 100_000 + "]" * 100_000, f"a model document nests at most {MAX_DEPTH} levels"),
    (lambda: {"format": "streamid.model/1", "x": json.loads("[" * 40 + "]" * 40)}, f"nests at most {MAX_DEPTH}"),
    (lambda: _doc(3, width=1e-300), "widths must be > 0, at least 1e-150 (1 / (2 w^2) must be a finite float64); got 1e-300"),
    (lambda: _doc(3, lag=10**9), f"lag must be in [0, {MAX_LAG}]; got 1000000000"),
    (lambda: _doc(999, regressors=1100), f"holds 1100898 parameters"),
    (lambda: {**_doc(3), "normalisation": {"u_low": [0.0], "u_high": [1.0], "y_low": 0.0, "y_high": 1e-70}},
     "spans (high - low) must be finite and >= 1e-60"),
])
def test_validate_refuses_hostile_models_in_one_line_before_building_anything(
        tmp_path: Path, make: Any, says: str) -> None:
    """Was: 100,000 neurons took 8.2 GB and exited 0; 1,000,000 a traceback (26 GiB); deep JSON a RecursionError
    traceback; widths 1e-300 parsed and then Predictor raised ZeroDivisionError."""
    doc = make()
    model = tmp_path / "m.json"
    model.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    r, mb = _max_rss_mb([*STREAMID, "validate", str(model), str(_record(tmp_path / "r.csv"))])
    line = _one_line_exit_2(r)
    assert says in line and "m.json" in line, line
    assert mb < 600, mb  # a bound on memory (the file is at most 34 MB), not on time


def test_models_from_every_reader_are_bounded_the_same_way() -> None:
    """Model.from_json (state, client), Model.from_dict (a model update's field) and the Predictor."""
    from streamid import Predictor

    with pytest.raises(ModelFormatError, match="100000 neurons"):
        Model.from_json(json.dumps(_doc(100_000)))
    with pytest.raises(ModelFormatError, match="nests at most"):
        Model.from_json(b"[" * 100_000 + b"]" * 100_000)
    with pytest.raises(ModelFormatError, match="at least 1e-150"):
        Model([Regressor("y", 0, 1)], np.zeros((1, 1)), np.array([1e-300]), np.ones(1),  # type: ignore[arg-type]
              Normalisation((-1.0,), (1.0,), -1.0, 1.0))
    big = Model((Regressor("y", 0, MAX_LAG + 5),), np.zeros((1, 1)), np.ones(1), np.ones(1),
                Normalisation((-1.0,), (1.0,), -1.0, 1.0))
    with pytest.raises(DataError, match=f"lags up to {MAX_LAG}"):
        Predictor(big)
    deep = {**_doc(3), "metrics": json.loads('{"a":' * 100 + '1' + '}' * 100)}  # deep, within Python's parser
    with pytest.raises(ModelFormatError, match=f"nests at most {MAX_DEPTH}"):
        Model.from_dict(deep)  # the client's path: a model update's parsed "model" field
    ok = Model.from_dict(_doc(3))
    assert Predictor(ok).model is ok and MAX_PARAMETERS >= 1000 * (200 + 2)


def test_model_files_with_a_bom_are_read_and_other_encodings_named(tmp_path: Path) -> None:
    text = json.dumps(_doc(3))
    for enc in ("utf-8-sig", "utf-16"):
        p = tmp_path / f"{enc}.json"
        p.write_bytes(text.encode(enc))
        assert Model.load(p).neurons == 3, enc
    p = tmp_path / "latin1.json"
    p.write_bytes(text.replace('"y"', '"\xb5"').encode("latin-1"))
    r = subprocess.run([*STREAMID, "validate", str(p), str(_record(tmp_path / "r.csv"))], capture_output=True,
                       text=True, timeout=120)
    line = _one_line_exit_2(r)
    assert "must be UTF-8 JSON text" in line and "latin1.json" in line, line


def test_cut_or_odd_mat_files_are_one_line_errors(tmp_path: Path) -> None:
    """Was: a .mat cut to 100 bytes gave an IndexError or MatReadError traceback (exit 1)."""
    from scipy.io import savemat

    full = tmp_path / "full.mat"
    t = np.arange(2000) * 0.01
    savemat(full, {"u": np.sin(t), "y": np.cos(t)})
    raw = full.read_bytes()
    cases = {"cut100.mat": raw[:100], "cut200.mat": raw[:200], "cut-half.mat": raw[: len(raw) // 2],
             "garbage.mat": raw[:128] + bytes(range(256)) * 8, "empty.mat": b""}
    for name, data in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        r = subprocess.run([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"], capture_output=True,
                           text=True, timeout=120)
        line = _one_line_exit_2(r)
        assert name in line, line


def test_a_huge_row_stops_the_file_with_bounded_memory(tmp_path: Path) -> None:
    """Was: one 200 MB CSV row took 1.1 GB and 31 s and ended with a confusing message."""
    p = tmp_path / "huge.csv"
    with open(p, "w") as fh:
        fh.write("t,u,y\n0,1,2\n")
        fh.write("1," + "9" * (100 << 20) + ",3\n")  # a 100 MB row
        fh.write("2,1,2\n")
    r, mb = _max_rss_mb([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"])
    line = _one_line_exit_2(r)
    assert f"line 3 is longer than {MAX_LINE_CHARS} characters" in line, line
    assert mb < 400, mb  # the row is never held whole (was ~5.5x the row)


def test_utf16_and_bom_text_is_read_or_named(tmp_path: Path) -> None:
    """Was: a UTF-16 CSV gave a raw codec error."""
    text = "t,u,y\n" + "".join(f"{i * 0.01:.2f},{np.sin(i):.6f},{np.cos(i):.6f}\n" for i in range(300))
    ref = tmp_path / "utf8.csv"
    ref.write_text(text, encoding="utf-8")
    want = load_table(ref).columns
    for enc in ("utf-8-sig", "utf-16", "utf-16-le", "utf-32"):
        p = tmp_path / f"{enc}.csv"
        data = text.encode(enc)
        if enc == "utf-16-le":
            data = b"\xff\xfe" + data  # a BOM, as Windows writes it
        p.write_bytes(data)
        got = load_table(p).columns
        assert list(got) == list(want) and all(np.array_equal(got[k], want[k]) for k in want), enc
    bare = tmp_path / "utf16-no-bom.csv"
    bare.write_bytes(text.encode("utf-16-le"))
    with pytest.raises(DataError, match=r"holds NUL bytes, which no text CSV has \(UTF-16 without a byte-order mark\?\)"):
        load_table(bare)
    latin = tmp_path / "latin1.csv"
    latin.write_bytes("t,u,\xb5y\n0,1,2\n1,2,3\n".encode("latin-1"))
    r = subprocess.run([*STREAMID, "identify", str(latin), "--input", "u", "--output", "y"], capture_output=True,
                       text=True, timeout=120)
    line = _one_line_exit_2(r)
    assert "is not UTF-8 text (byte 0xb5" in line and "save it as UTF-8" in line, line


def test_hints_name_only_flags_that_exist(tmp_path: Path) -> None:
    """Was: a damaged log's error advised --partial, which neither identify nor validate accepts."""
    from streamid.logs.bundled import bundled_log

    cut = tmp_path / "cut.mcap"
    raw = Path(bundled_log("mr_damper.mcap")).read_bytes()
    cut.write_bytes(raw[: len(raw) // 2])
    model = tmp_path / "m.json"
    model.write_text(json.dumps(_doc(3)))
    helps = {c: subprocess.run([*STREAMID, c, "--help"], capture_output=True, text=True, timeout=60).stdout
             for c in ("identify", "validate", "replay")}  # once: the same help texts serve both commands' errors
    for args in (["identify", str(cut)], ["validate", str(model), str(cut)]):
        r = subprocess.run([*STREAMID, *args], capture_output=True, text=True, timeout=120)
        line = _one_line_exit_2(r)
        import re

        for m in re.finditer(r"(?:`streamid (\w+) )?(--[a-z][a-z-]+)", line):
            command = m.group(1) or args[0]
            assert m.group(2) in helps[command], (command, m.group(2), line)
        assert "streamid replay --partial" in line, line
