"""``streamid validate`` on a record longer than one chunk, read and judged a piece at a time (issue 53 item 2):
the report equals the whole record's (``assess`` on the same arrays; the whole-file path of the command for the
notes, caveats and how it was read), and its memory does not grow with the record."""

from __future__ import annotations

import io
import json
import sys
import tracemalloc
from contextlib import redirect_stdout
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).parent))
from test_engine_ensemble import _members  # noqa: E402 - the hand-made networks of the ensemble tests

import streamid.commands.validate_run as vr  # noqa: E402
from streamid.commands.main import main  # noqa: E402
from streamid.engine.validation import assess  # noqa: E402
from streamid.model.ensemble import ensemble_of  # noqa: E402
from streamid.model.limits import CHUNK_ROWS  # noqa: E402
from streamid.model.narx import Model  # noqa: E402
from streamid.model.uncertainty import BEYOND, LEVELS, Interval  # noqa: E402

N = 200_000  # ~3 chunks
PERIOD_S = 0.001
INTERVAL = Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100, beyond=BEYOND)


def _record(n: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """``y(t) = 0.6 y(t-1) + tanh(u(t-1)) - 0.2 u(t-3)`` plus noise (what the hand-made networks roughly model)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    x = np.zeros(n)
    x[1:] += np.tanh(u[:-1])
    x[3:] -= 0.2 * u[:-3]
    return u, lfilter([1.0], [1.0, -0.6], x) + 0.01 * rng.normal(size=n)


def _write(path: Path, u: np.ndarray, y: np.ndarray, clock: bool = True) -> None:
    import pyarrow as pa

    cols = {**({"time_s": np.arange(len(y)) * PERIOD_S} if clock else {}), "volt": u, "um": y}
    if path.suffix == ".csv":
        with open(path, "w") as fh:
            fh.write(",".join(cols) + "\n")
            np.savetxt(fh, np.column_stack(list(cols.values())), delimiter=",", fmt="%.17g")
    elif path.suffix == ".parquet":
        import pyarrow.parquet as pq

        pq.write_table(pa.table(cols), path)
    else:
        import pyarrow.feather as pf

        pf.write_feather(pa.table(cols), path, chunksize=50_000)


def _run(args: list[str], streamed: bool) -> dict[str, Any]:
    """The command's JSON report; ``streamed`` False: the whole-file path (today's), True: the file must be read a
    piece at a time (reading it whole fails the test)."""
    real_whole, real_streamed = vr._whole, vr._streamed

    def no_whole(*a: Any, **k: Any) -> Any:
        raise AssertionError("the whole-file path was taken")

    vr._whole, vr._streamed = (no_whole, real_streamed) if streamed else (real_whole, lambda *a, **k: None)
    try:
        out = io.StringIO()
        with redirect_stdout(out):
            assert main(["validate", *args, "--json"]) == 0
    finally:
        vr._whole, vr._streamed = real_whole, real_streamed
    return dict(json.loads(out.getvalue()))


def _close(got: Any, want: Any, rel: float = 1e-9) -> bool:
    return got is None and want is None or abs(got - want) <= rel * abs(want)


def _same_report(got: dict[str, Any], want: dict[str, Any]) -> None:
    """R^2, RMSE and the band's width within 1e-9 relative, counts exactly, correlations within 1e-9 absolute,
    everything else identical."""
    for part in ("r2", "rmse", "fit_percent"):
        for k in want[part]:
            assert _close(got[part][k], want[part][k]), (part, k, got[part][k], want[part][k])
    for k in ("n", "n_scored", "fr_diverged_at", "outside_domain"):
        assert got[k] == want[k], k
    if want["interval"] is None:
        assert got["interval"] is None
    else:
        assert got["interval"]["coverage"] == want["interval"]["coverage"]
        for k in ("width", "width_over_std"):
            assert _close(got["interval"][k], want["interval"][k]), k
        assert got["interval"]["width_from"].keys() == want["interval"]["width_from"].keys()
        for k, v in want["interval"]["width_from"].items():  # what makes the band wide, summed the same way
            assert _close(got["interval"]["width_from"][k], v), k
    gc, wc = got["correlation"], want["correlation"]
    assert (gc["n"], gc["band"], list(gc["tests"])) == (wc["n"], wc["band"], list(wc["tests"]))
    for name, t in wc["tests"].items():
        g = gc["tests"][name]
        assert g["lags"] == t["lags"]
        assert np.max(np.abs(np.subtract(g["values"], t["values"]))) <= 1e-9, name
        assert g["passed"] == t["passed"]


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Model]]:
    d = tmp_path_factory.mktemp("models")
    out = {}
    for name, m in (("ensemble", replace(ensemble_of(_members()), interval=INTERVAL)),
                    ("single", replace(_members()[2], interval=INTERVAL))):
        m = replace(m, window={"period_ns": round(PERIOD_S * 1e9), "n_samples": 1000})
        m.save(d / f"{name}.json")
        out[name] = (d / f"{name}.json", m)
    return out


@pytest.mark.parametrize("suffix,kind", [(".parquet", "ensemble"), (".feather", "single"), (".csv", "ensemble")])
def test_streamed_report_equals_the_whole_records(tmp_path: Path, models: dict[str, tuple[Path, Model]],
                                                   suffix: str, kind: str) -> None:
    path, model = models[kind]
    u, y = _record(N)
    data = tmp_path / f"rec{suffix}"
    _write(data, u, y)
    got = _run([str(path), str(data)], streamed=True)
    whole = _run([str(path), str(data)], streamed=False)
    _same_report(got, assess(model, u, y, keep=False).to_dict())
    _same_report(got, whole)
    for k in ("notes", "caveats", "data", "model", "passed"):
        assert got[k] == whole[k], k
    assert got["data"]["read"]["clock"] == "time_s" and got["data"]["period_ns"] == 1_000_000


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_start_and_end_pick_the_same_rows(tmp_path: Path, models: dict[str, tuple[Path, Model]], suffix: str) -> None:
    path, model = models["single"]
    u, y = _record(N)
    data = tmp_path / f"rec{suffix}"
    _write(data, u, y)
    for span in (["--start", "12.5", "--end", "180"], ["--start", "30"], ["--end", "150.0005"]):
        got = _run([str(path), str(data), *span], streamed=True)
        whole = _run([str(path), str(data), *span], streamed=False)
        _same_report(got, whole)
        assert got["data"] == whole["data"] and got["notes"] == whole["notes"] and got["caveats"] == whole["caveats"]
        a, b = (int(v) for v in whole["data"]["span"].split(" ")[1].split(".."))
        _same_report(got, assess(model, u[a : b + 1], y[a : b + 1], keep=False).to_dict())


def test_no_clock_uses_the_models_period_and_a_short_span_reads_whole(tmp_path: Path,
                                                                       models: dict[str, tuple[Path, Model]]) -> None:
    path, model = models["ensemble"]
    u, y = _record(N)
    data = tmp_path / "rec.parquet"
    _write(data, u, y, clock=False)
    got = _run([str(path), str(data), "--start", "20"], streamed=True)
    assert got["data"]["span"] == _run([str(path), str(data), "--start", "20"], streamed=False)["data"]["span"]
    assert got["notes"] and "has no clock" in got["notes"][0]
    _same_report(got, assess(model, u[20_000:], y[20_000:], keep=False).to_dict())
    # a span of one chunk or less: today's path (the same bits as assess), never the streamed one
    with pytest.raises(AssertionError, match="whole-file path"):
        _run([str(path), str(data), "--end", str(CHUNK_ROWS * PERIOD_S / 2)], streamed=True)


def test_a_diverging_free_run_is_named_at_the_same_sample(tmp_path: Path) -> None:
    doc = {"format": "streamid.model/2", "inputs": ["volt"], "output": "um",
           "regressors": [{"signal": "y", "index": 0, "lag": 1}, {"signal": "u", "index": 0, "lag": 1}],
           "normalisation": {"u_low": [-1.0], "u_high": [1.0], "y_low": -1.0, "y_high": 1.0},
           "centres": [[0.0, 0.0]], "widths": [1.0], "weights": [0.0], "linear": [1.003, 0.1, 0.0],
           "metrics": {}, "window": {"n_samples": 1000}}
    (tmp_path / "m.json").write_text(json.dumps(doc))
    model = Model.load(tmp_path / "m.json")
    u, y = _record(N)
    data = tmp_path / "rec.parquet"
    _write(data, u, y)
    got = _run([str(tmp_path / "m.json"), str(data)], streamed=True)
    want = assess(model, u, y, keep=False).to_dict()
    assert CHUNK_ROWS < want["fr_diverged_at"] < N  # in a later piece than the first
    _same_report(got, want)
    assert got["caveats"] == _run([str(tmp_path / "m.json"), str(data)], streamed=False)["caveats"]


def _peak_bytes(model: Path, data: Path) -> int:
    tracemalloc.start()
    try:
        _run([str(model), str(data)], streamed=True)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_record(tmp_path: Path, models: dict[str, tuple[Path, Model]]) -> None:
    """Validating 900,000 samples peaks (Python and numpy allocations, tracemalloc) within 1 MB of 300,000: the
    record's own arrays would be 16 bytes a sample, 9.6 MB more (the residual 4.8 MB more)."""
    path = models["single"][0]
    peaks = []
    for n in (300_000, 900_000):
        u, y = _record(n, seed=n)
        data = tmp_path / f"rec{n}.parquet"
        _write(data, u, y)
        _run([str(path), str(data)], streamed=True)  # compiled kernels and imports first
        peaks.append(_peak_bytes(path, data))
    assert peaks[1] - peaks[0] < 1_000_000, peaks
