"""Missing and infinite values in a record read a piece at a time (issue 53 item 2): ``--fill``, ``--drop`` and the
error naming the rows give what the whole file gives (``logs.gaps.GapStream`` against ``logs.columns.handle_missing``
on random gaps cut into random pieces; ``streamid validate`` streamed against its whole-file path on Parquet and CSV
files), and memory stays bounded by the piece."""

from __future__ import annotations

import io
import sys
import tracemalloc
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_validate_streamed import _record, _run, _same_report, _write, models  # noqa: E402,F401 - its fixture too

import streamid.commands.validate_run as vr  # noqa: E402
import streamid.logs.gaps as gaps  # noqa: E402
from streamid.commands.main import main  # noqa: E402
from streamid.errors import DataError  # noqa: E402
from streamid.logs.columns import handle_missing  # noqa: E402
from streamid.logs.pieces import PieceReader  # noqa: E402
from streamid.model.narx import Model  # noqa: E402

N = 200_000


def _holes(rng: np.random.Generator, n: int, places: int, longest: int) -> dict[str, np.ndarray]:
    """Two columns of ``n`` rows and a time, with ``places`` runs of missing values (either or both columns,
    overlapping), some at the start and the end."""
    cols = {"a": rng.normal(size=n), "b": rng.normal(size=n)}
    for _ in range(places):
        at, k = int(rng.integers(0, n)), int(rng.integers(1, longest + 1))
        for c in rng.choice(["a", "b"], size=int(rng.integers(1, 3)), replace=False):
            s = at + int(rng.integers(0, 3))
            cols[str(c)][s : s + k] = np.nan
    if rng.random() < 0.4:
        cols["b"][: int(rng.integers(1, 50))] = np.nan
    if rng.random() < 0.4:
        cols["a"][-int(rng.integers(1, 50)) :] = np.nan
    return cols


def _streamed(cols: dict[str, np.ndarray], policy: str, cuts: np.ndarray,
              lines: np.ndarray | None) -> tuple[dict[str, np.ndarray], np.ndarray, list[str], dict[str, Any]]:
    g = gaps.GapStream(list(cols), policy)
    t = np.arange(len(cols["a"]), dtype=np.int64) * 7
    out: list[tuple[dict[str, np.ndarray], np.ndarray | None]] = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        out += g.feed({c: v[a:b] for c, v in cols.items()}, t[a:b])
    notes, counts = g.finish("rec.csv", lines)
    kept = {c: np.concatenate([p[0][c] for p in out]) if out else np.empty(0) for c in cols}
    times = np.concatenate([p[1] for p in out if p[1] is not None]) if out else np.empty(0, dtype=np.int64)
    return kept, times, notes, counts


@pytest.mark.parametrize("policy", ["fill", "drop", "error"])
def test_gaps_a_piece_at_a_time_equal_the_whole_columns(policy: str) -> None:
    """Random gaps (at the ends, inside, across pieces, one column or both) cut into random pieces (single rows
    too): the same kept rows to the bit, times, notes, counts, and the same errors."""
    rng = np.random.default_rng(53)
    seen = set()
    for trial in range(60):
        n = int(rng.integers(30, 3000))
        cols = _holes(rng, n, int(rng.integers(0, 40)), int(rng.choice([1, 3, 40, 400])))
        if trial % 7 == 3:
            cols["b"][int(rng.integers(0, n))] = np.inf * rng.choice([-1, 1])
        if trial % 11 == 5:
            cols["a"][:] = np.nan
        sizes = rng.choice([1, 2, 17, 100, 700], size=n)
        cuts = np.unique(np.concatenate([[0], np.minimum(np.cumsum(sizes), n), [n]]))
        lines = np.arange(n) + 2 + (np.arange(n) > n // 2) if trial % 2 else None
        t = np.arange(n, dtype=np.int64) * 7
        try:
            want = handle_missing("rec.csv", cols, policy, lines)
        except DataError as exc:
            with pytest.raises(DataError) as got:
                _streamed(cols, policy, cuts, lines)
            assert str(got.value) == str(exc)
            seen.add(str(exc).split(":")[1][:12])
            continue
        kept, times, notes, counts = _streamed(cols, policy, cuts, lines)
        for c in cols:
            assert np.array_equal(kept[c], want.columns[c]), (trial, c)  # to the bit (no NaN is kept)
        assert np.array_equal(times, t[want.keep]) and notes == list(want.notes), trial
        assert counts == {"policy": policy, "rows_with_missing": want.rows_missing, "rows_dropped": want.dropped,
                          "values_filled": want.filled, "places_spacing_broken": want.gaps}
        seen.add(" ".join(note.split(" ")[0] + str(note.startswith("cut 0 ")) for note in want.notes))
    assert len(seen) >= 4, seen  # errors and reports (rows cut at the start or not) met


def test_a_long_run_is_held_only_up_to_the_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """--fill holds a run of at most MAX_GAP_ROWS rows: a longer one inside the record raises LongGap (the file
    is then read whole), one the record ends in is cut as the whole path cuts it."""
    monkeypatch.setattr(gaps, "MAX_GAP_ROWS", 50)
    rng = np.random.default_rng(1)
    cols = {"a": rng.normal(size=1000), "b": rng.normal(size=1000)}
    cols["b"][900:] = np.nan  # the end: 100 rows > 50
    cuts = np.arange(0, 1001, 10)
    kept, _, notes, _ = _streamed(cols, "fill", cuts, None)
    want = handle_missing("rec.csv", cols, "fill")
    assert np.array_equal(kept["b"], want.columns["b"]) and notes == list(want.notes)
    cols["b"][950:] = 1.0  # now inside: 50 rows, held
    assert np.array_equal(_streamed(cols, "fill", cuts, None)[0]["b"], handle_missing("rec.csv", cols, "fill").columns["b"])
    cols["b"][899] = np.nan  # 51 rows
    with pytest.raises(gaps.LongGap, match="run of 51 rows"):
        _streamed(cols, "fill", cuts, None)
    assert _streamed(cols, "drop", cuts, None)[2] == list(handle_missing("rec.csv", cols, "drop").notes)


def _gappy(path: Path, seed: int = 7, n: int = N) -> None:
    """A record with missing values: two rows at the start, a gap inside a piece (the columns' runs overlapping),
    one across each of the first two piece boundaries (Parquet's 65,536-row batches, the CSV's blocks), and three
    rows at the end (27 rows)."""
    u0, y0 = _record(n, seed)
    _write(path, u0, y0)
    for _ in range(3):  # a CSV's blocks end where its bytes say: written with the gaps, they move a little
        ends = np.cumsum([len(c["um"]) for c, _ in PieceReader(str(path), ["volt"], "um")._batches()])[:2]
        u, y = u0.copy(), y0.copy()
        y[:2] = np.nan
        u[1000:1004] = np.nan
        y[1002:1008] = np.nan
        for b in ends:
            u[b - 3 : b + 2] = np.nan
            y[b - 1 : b + 4] = np.nan
        y[-3:] = np.nan
        _write(path, u, y)
        now = np.cumsum([len(c["um"]) for c, _ in PieceReader(str(path), ["volt"], "um")._batches()])[:2]
        if np.all(np.abs(now - ends) <= 3):
            return  # each gap spans a boundary
    raise AssertionError(f"the gaps could not be put across the pieces' boundaries: {ends}, {now}")


def _fails(args: list[str], streamed: bool) -> str:
    """The command's one-line error (exit 2), by the streamed or the whole-file path."""
    real_whole, real_streamed = vr._whole, vr._streamed

    def no_whole(*a: Any, **k: Any) -> Any:
        raise AssertionError("the whole-file path was taken")

    vr._whole, vr._streamed = (no_whole, real_streamed) if streamed else (real_whole, lambda *a, **k: None)
    err = io.StringIO()
    try:
        with redirect_stdout(io.StringIO()), redirect_stderr(err):
            assert main(["validate", *args, "--json"]) == 2
    finally:
        vr._whole, vr._streamed = real_whole, real_streamed
    lines = err.getvalue().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("streamid validate: error: "), lines
    return lines[0]


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_fill_and_drop_streamed_give_the_whole_files_report(tmp_path: Path, models: dict[str, tuple[Path, Model]],
                                                             suffix: str) -> None:
    path = models["ensemble"][0]
    data = tmp_path / f"rec{suffix}"
    _gappy(data)
    for flag in ("--fill", "--drop"):
        got = _run([str(path), str(data), flag], streamed=True)
        whole = _run([str(path), str(data), flag], streamed=False)
        _same_report(got, whole)
        for k in ("notes", "caveats", "data", "model", "passed"):
            assert got[k] == whole[k], (flag, k, got[k], whole[k])
        missing = got["data"]["read"]["missing"]
        assert missing["rows_with_missing"] == 2 + 8 + 2 * 7 + 3 and got["data"]["warnings"], missing
        assert got["data"]["warnings"][0].startswith("cut 2 rows at the start and 3 at the end")
    span = ["--fill", "--start", "60", "--end", "140"]  # rows picked by the clock after the cut rows
    assert _run([str(path), str(data), *span], streamed=True)["data"] == _run([str(path), str(data), *span],
                                                                              streamed=False)["data"]


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_missing_values_stop_it_with_the_whole_files_errors(tmp_path: Path, models: dict[str, tuple[Path, Model]],
                                                            suffix: str) -> None:
    path = models["single"][0]
    data = tmp_path / f"rec{suffix}"
    _gappy(data)
    err = _fails([str(path), str(data)], streamed=True)
    assert err == _fails([str(path), str(data)], streamed=False)
    first = "line 2 (um); line 3 (um); line 1002 (volt)" if suffix == ".csv" else "sample 1 (um); sample 2 (um)"
    assert f"27 rows of {N} have" in err and first in err and "; and 22 more" in err
    u, y = _record(N)
    y[::90] = np.nan  # 2,222 places inside a record of 200,000 rows: over one per 100
    _write(data, u, y)
    err = _fails([str(path), str(data), "--drop"], streamed=True)
    assert err == _fails([str(path), str(data), "--drop"], streamed=False) and "at 2222 places" in err
    y[::90] = np.inf * (-1) ** np.arange(y[::90].size)
    y[10] = np.nan
    _write(data, u, y)
    err = _fails([str(path), str(data), "--fill"], streamed=True)
    assert err == _fails([str(path), str(data), "--fill"], streamed=False) and "inf is not a finite number" in err


def test_a_fill_run_longer_than_a_chunk_is_read_whole_and_said(tmp_path: Path,
                                                               models: dict[str, tuple[Path, Model]]) -> None:
    path = models["single"][0]
    u, y = _record(N)
    y[70_000:140_000] = np.nan  # 70,000 rows inside: more than MAX_GAP_ROWS
    data = tmp_path / "rec.parquet"
    _write(data, u, y)
    err = io.StringIO()
    with redirect_stderr(err):
        with pytest.raises(AssertionError, match="whole-file path"):
            _run([str(path), str(data), "--fill"], streamed=True)
    assert "reading" in err.getvalue() and "whole" in err.getvalue() and "70000 rows" in err.getvalue()
    u, y = _record(N)
    y[120_000:] = np.nan  # 80,000 rows the record ends in: cut, streamed
    _write(data, u, y)
    got = _run([str(path), str(data), "--fill"], streamed=True)
    _same_report(got, _run([str(path), str(data), "--fill"], streamed=False))
    assert got["data"]["warnings"] == ["cut 0 rows at the start and 80000 at the end of the record (a missing value "
                                       "in a column used); the sample spacing is kept"]


def _peak_bytes(model: Path, data: Path) -> int:
    tracemalloc.start()
    try:
        _run([str(model), str(data), "--fill"], streamed=True)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_with_missing_values_does_not_grow_with_the_record(tmp_path: Path,
                                                                  models: dict[str, tuple[Path, Model]]) -> None:
    """With gaps (inside a piece, across pieces, at the ends) validating 900,000 samples under --fill peaks
    (tracemalloc) within 1 MB of 300,000: the record's own arrays would be 9.6 MB more."""
    path = models["single"][0]
    peaks = []
    for n in (300_000, 900_000):
        data = tmp_path / f"rec{n}.parquet"
        _gappy(data, seed=n, n=n)
        _run([str(path), str(data), "--fill"], streamed=True)  # compiled kernels and imports first
        peaks.append(_peak_bytes(path, data))
    assert peaks[1] - peaks[0] < 1_000_000, peaks
