"""Caveats on a kept model (streamid.engine.choice.caveats): each raised by the figure it names, none on good data;
``streamid identify`` prints them under the kept model and reports them (a real subprocess on a bundled record)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from conftest import STREAMID
from streamid.model.domain import BEYOND_RANGE
from streamid.engine.choice.caveats import MARGINAL_RADIUS, arx_pole_radius, model_caveats

ROOT = Path(__file__).resolve().parents[1]
GOOD = {"osa_est": 0.999, "fr_est": 0.98, "osa_val": 0.998, "fr_val": 0.97}


def _stable(n: int, seed: int, amplitude: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    u = amplitude * np.random.default_rng(seed).uniform(-1, 1, n)
    return u, lfilter([0.0, 1.0], [1.0, -1.5, 0.7], u)  # poles at radius sqrt(0.7)


def test_the_arx_pole_radius_of_known_plants() -> None:
    u, y = _stable(2000, 0)
    assert abs(arx_pole_radius(u, y) - np.sqrt(0.7)) < 1e-6
    integrating = np.cumsum(lfilter([0.0, 1.0], [1.0, -0.5], u))  # a pole at 1
    assert arx_pole_radius(u, integrating) > MARGINAL_RADIUS
    assert np.isnan(arx_pole_radius(u[:10], y[:10]))  # too short to fit


def test_good_data_and_figures_raise_no_caveat() -> None:
    u, y = _stable(4000, 1)
    assert model_caveats(GOOD, u[:2000], y[:2000], u[2000:], y[2000:]) == []


def test_validation_beyond_the_estimation_range_is_named_with_both_ranges() -> None:
    u, y = _stable(2000, 2)
    uv, yv = _stable(2000, 3, amplitude=2.0)  # twice the estimation excitation
    out = model_caveats(GOOD, u, y, uv, yv, ("volt",), "um")
    assert len(out) == 2 and out[0].startswith("the validation input volt spans") and "output um" in out[1]
    assert "does not extrapolate" in out[1] and f"[{y.min():.4g}, {y.max():.4g}]" in out[1]
    lo, hi, span = y.min(), y.max(), y.max() - y.min()
    within = np.clip(yv, lo - 0.9 * BEYOND_RANGE * span, hi + 0.9 * BEYOND_RANGE * span)  # inside the allowance
    assert not any("output" in c for c in model_caveats(GOOD, u, y, u, within))


def test_a_one_step_predictor_that_cannot_simulate_says_why_when_the_plant_integrates() -> None:
    u, y = _stable(2000, 4)
    poor = {**GOOD, "fr_val": -3.5}
    out = model_caveats(poor, u[:1000], y[:1000], u[1000:], y[1000:])
    assert out == [out[0]] and out[0].startswith("a one-step predictor, not a simulator") and "-3.5000" in out[0]
    assert "pole" not in out[0]  # a stable plant: no such reason
    integ = np.cumsum(y)
    out = model_caveats(poor, u[:1000], integ[:1000], u[1000:], integ[1000:] - integ[1000] + integ[999])
    assert any("integrates or is unstable" in c for c in out)
    assert model_caveats({**poor, "osa_val": 0.5}, u[:1000], y[:1000], u[1000:], y[1000:]) == []  # not a good predictor


def test_a_free_run_worse_than_the_mean_on_its_own_record() -> None:
    u, y = _stable(1000, 5)
    out = model_caveats({**GOOD, "fr_est": -0.2}, u, y, None, None)
    assert len(out) == 1 and "does not explain even its estimation record (free-run R2 -0.2000)" in out[0]


def test_identify_prints_and_reports_the_ball_and_beams_caveats(tmp_path: Path) -> None:
    csv = ROOT / "streamid" / "data" / "suite" / "ball_and_beam.csv"
    report = tmp_path / "r.json"
    p = subprocess.run([*STREAMID, "identify", str(csv), "--input", "u", "--output", "y", "--est", "500",
                        "--report", str(report)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    kept = next(i for i, ln in enumerate(lines) if ln.startswith("kept: "))
    printed = [ln[len("caveat: "):] for ln in lines[kept + 1 :] if ln.startswith("caveat: ")]
    got = json.loads(report.read_text())["caveats"]
    assert printed == got and len(got) in (3, 4)
    assert "validation input u spans" in got[0] and "validation output y spans" in got[1]
    assert "a one-step predictor, not a simulator" in got[2]
    assert "integrates or is unstable in open loop" in got[2]  # its second-order ARX pole: 0.998
    # and where the kept one-step predictor's free run does not explain the estimation record either, that too
    # (eight restarts: the fittest one-step predictor free-runs it at R2 -1.30)
    assert got[3:] == [c for c in got if "does not explain even its estimation record" in c]


def test_a_kept_model_much_larger_than_a_close_competitor_is_named_with_it() -> None:
    """Issue 37's real piezo: 30 neurons, lags up to 30 and a linear part kept for an estimation free-run R² of
    0.99992 against 0.99988 of a 10-neuron, 10-lag restart (-3.96 on the next record)."""
    from streamid.engine.choice.caveats import size_caveat

    cx = {"rule": "aic", "candidates": [
        {"run": 0, "neurons": 30, "lag_space": 30, "linear": True, "params": 61, "r2_fr_est": 0.99992},
        {"run": 1, "neurons": 10, "lag_space": 10, "linear": False, "params": 10, "r2_fr_est": 0.99988},
        {"run": 2, "neurons": 8, "lag_space": 10, "linear": False, "params": 8, "r2_fr_est": 0.9990},  # not close
        {"run": 3, "neurons": 30, "lag_space": 10, "linear": False, "params": 30, "r2_fr_est": None},  # inadmissible
    ]}
    (text,) = size_caveat(61, 0.99992, cx)
    assert "fits 61 weights, 6.1 times the 10 of restart 1's (10 neurons, lags 1..10)" in text
    assert "0.99988 is close to the kept one's 0.99992" in text and "by aic" in text
    assert "--validate SECOND_RECORD" in text and "--neurons 10 --max-lag 10" in text
    assert size_caveat(15, 0.99992, cx) == []  # not twice as large as any close candidate
    assert size_caveat(61, 0.9999999, cx) == []  # the kept one's error is far smaller: no close competitor
    assert size_caveat(61, None, cx) == [] and size_caveat(61, 0.99992, None) == []
