"""A free run that diverges never takes a report down (issue 37, item 3).

A model whose free run leaves the numbers (an unstable linear part: ``yn(t) = 1.5 yn(t-1) + ...``) is judged by
the real code paths: ``validate``/``assess`` give its free-run R² as None and name the sample, ``streamid identify``'s
report rows and statistics carry it beside a finite run (which is the one kept), and the real ``streamid validate``
CLI prints "diverged", writes null in its JSON and exits 0 (1 with ``--min-r2-fr``), with a caveat naming it.
"""

from __future__ import annotations

import io
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import STREAMID

from streamid.commands.identify_run import _best_index, _print_report, _stats, validated_run
from streamid.engine.choice.caveats import model_caveats
from streamid.model.narx import Model
from streamid.engine.settings import DEFAULT
from streamid.engine.validation import assess, validate
from streamid.logs.datafile import Dataset

N = 3000  # 1.5 ** 1750 overflows a double: the unstable model's free run diverges within the record


def linear_model(a_y: float) -> Model:
    """``yn(t) = a_y yn(t-1) + 0.1 un(t-1)`` (one Gaussian of weight 0 beside the linear part: a ``streamid.model/2``
    file)."""
    doc = {
        "format": "streamid.model/2", "inputs": ["force"], "output": "pos",
        "regressors": [{"signal": "y", "index": 0, "lag": 1}, {"signal": "u", "index": 0, "lag": 1}],
        "normalisation": {"u_low": [-1.0], "u_high": [1.0], "y_low": -1.0, "y_high": 1.0},
        "centres": [[0.0, 0.0]], "widths": [1.0], "weights": [0.0], "linear": [a_y, 0.1, 0.0],
        "metrics": {}, "window": {"n_samples": N},
    }
    return Model.from_json(json.dumps(doc))


def record(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A stable first-order plant's record (what the stable model describes)."""
    u = np.random.default_rng(seed).uniform(-1, 1, N)
    y = np.zeros(N)
    for t in range(1, N):
        y[t] = 0.5 * y[t - 1] + 0.1 * u[t - 1]
    return u, y


def test_validate_and_assess_report_a_divergence_instead_of_failing() -> None:
    u, y = record(0)
    bad = linear_model(1.5)
    rep = validate(bad, u[:1500], y[:1500], u, y)
    assert rep.fr_est is None and rep.fr_val is None  # no R² of a free run that left the numbers
    assert np.isfinite(rep.osa_val)  # the one-step prediction is still judged
    at = rep.diverged()
    assert set(at) == {"val"} or set(at) == {"est", "val"}
    assert 100 < at["val"] < N and not abs(rep.predictions["fr_val"][at["val"]]) <= 1e150
    assert np.all(np.abs(rep.predictions["fr_val"][: at["val"]]) <= 1e150)
    rec = assess(bad, u, y)
    assert rec.fr is None and rec.rmse_fr is None and rec.fr_diverged_at == at["val"]
    json.dumps(rec.to_dict(), allow_nan=False)  # JSON-able as it is: null, not NaN or Infinity
    good = assess(linear_model(0.5), u, y)
    assert good.fr is not None and good.fr > 0.999 and good.fr_diverged_at is None


def test_identify_report_keeps_the_other_runs_and_a_finite_model() -> None:
    u, y = record(1)
    ds = Dataset("rec.csv", ("force",), "pos", u[:2000, None], y[:2000], u[2000:, None], y[2000:], 2000)
    runs = [validated_run(m, ds, seed=s, seconds=0.1, evaluations=10, fitness=0.0, history=[0.0])
            for s, m in enumerate((linear_model(1.5), linear_model(0.5)))]
    assert runs[0]["r2"]["fr_est"] is None and "est" in runs[0]["diverged"]
    assert runs[1]["r2"]["fr_val"] is not None and runs[1]["diverged"] == {}
    assert _best_index(runs, DEFAULT) == 1  # chosen by the estimation free run: never the diverged one
    fr = _stats([r["r2"]["fr_val"] for r in runs])
    assert fr["diverged"] == 1 and fr["min"] == fr["max"] == runs[1]["r2"]["fr_val"]
    out = io.StringIO()
    _print_report(out, ds, DEFAULT, runs, 1, 0.2, [])
    text = out.getvalue()
    assert "diverged in 1 of 2 runs" in text
    assert text.count("diverged") >= 3  # the row's two free runs and the statistics line
    json.dumps(runs, allow_nan=False)
    caveats = model_caveats(runs[0]["r2"], ds.u_est, ds.y_est, ds.u_val, ds.y_val, ("force",), "pos",
                            runs[0]["diverged"])
    assert any("diverged" in c and str(runs[0]["diverged"]["val"]) in c for c in caveats)


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, *args], capture_output=True, text=True, timeout=120)


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path]:
    u, y = record(2)
    data = tmp_path / "rec.csv"
    np.savetxt(data, np.column_stack([np.arange(N) * 0.01, u, y]), delimiter=",", header="time_s,force,pos",
               comments="", fmt="%.12g")
    model = tmp_path / "unstable.json"
    model.write_text(linear_model(1.5).to_json())
    return model, data


def test_validate_cli_says_diverged(files: tuple[Path, Path]) -> None:
    model, data = files
    p = cli("validate", str(model), str(data))
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    line = next(ln for ln in p.stdout.splitlines() if ln.strip().startswith("free run"))
    assert "diverged" in line
    assert "caveat: its free run on the record diverged" in p.stdout
    j = cli("validate", str(model), str(data), "--json")
    assert j.returncode == 0, j.stderr
    doc = json.loads(j.stdout)
    assert doc["r2"]["fr"] is None and doc["rmse"]["fr"] is None and isinstance(doc["fr_diverged_at"], int)
    assert isinstance(doc["r2"]["osa"], float)
    gate = cli("validate", str(model), str(data), "--min-r2-fr", "0.5")
    assert gate.returncode == 1, gate.stdout + gate.stderr
    assert "FAILED: free-run R² diverged" in gate.stdout
