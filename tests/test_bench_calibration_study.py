"""benchmarks.calibration_study: its 'engine' variant is the engine's calibration, to the quantile and the band."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from benchmarks.calibration_study import FACTORS, VARIANTS, conformal, factors, features, score
from benchmarks.suite import Target
from streamid.engine.choice.calibration import calibrate
from streamid.engine.settings import RIDGE
from streamid.model.ensemble import ensemble_of
from streamid.model.uncertainty import conformal_quantiles
from test_engine_ensemble import U1, U3, Y1, Y2, _data, _net


def test_the_conformal_quantile_is_the_engines() -> None:
    scores = np.random.default_rng(3).exponential(1.0, 257)
    assert conformal(scores) == conformal_quantiles(scores, (0.9,))[0]


def test_the_engine_variant_gives_the_band_the_calibrated_model_draws() -> None:
    u, y = _data(700)
    ens = ensemble_of([_net(0, (Y1, U1)), _net(1, (Y1, Y2, U1, U3), 5), _net(2, (Y1, U1, U3), 3)], combine="median")
    t = Target("toy", "", u[:400].reshape(-1, 1), y[:400], u[400:].reshape(-1, 1), y[400:], kind="two-experiment")
    interval, _ = calibrate(ens, t.u_est, t.y_est, RIDGE)
    assert interval is not None
    f = features(ens, t)
    f["yhalf"] = np.float64(ens.normalisation.y_half_range)
    assert f["cal_y"].shape == (200,) and f["rev_y"].shape == (200 - ens.max_lag,)  # each half held out once
    make = VARIANTS["engine"](f)
    assert make is not None
    half = make((f["val_y"], f["val_centre"], f["val_spread"], f["val_far"]))
    band = replace(ens, interval=interval).simulate(t.u_val, t.y_val, interval=0.9)
    L = ens.max_lag
    np.testing.assert_allclose(half, (band.upper - band.y)[L:], rtol=1e-12, atol=1e-12)
    assert np.all(half > 0)


def _rate_row(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A run whose error grows with how fast it moves: still, then fast, then still (y, centre, rate)."""
    t = np.arange(n)
    freq = np.where((t > n // 3) & (t < 2 * n // 3), 0.3, 0.01)
    centre = np.sin(np.cumsum(freq))
    rate = np.abs(np.diff(centre, prepend=centre[:1]))
    return centre + rng.normal(0.0, 1.0, n) * (0.001 + 0.5 * rate), centre, rate


def test_the_rate_variant_follows_an_error_that_grows_with_the_free_runs_rate() -> None:
    rng = np.random.default_rng(5)
    n = 3000
    y, c, rate = _rate_row(rng, n)
    vy, vc, vrate = _rate_row(rng, n)
    zero = np.zeros(n)
    f = {"cal_y": y, "cal_centre": c, "cal_spread": zero, "cal_far": zero, "yhalf": np.float64(1.0),
         "h": np.array([n, 0.0])}
    engine, rate_band = VARIANTS["engine"](f), VARIANTS["rate"](f)
    assert engine is not None and rate_band is not None
    v = (vy, vc, zero, zero)
    he, hr = engine(v), rate_band(v)
    assert np.ptp(he) == 0.0  # the engine's band: one width where there is no spread and no far term
    fast = vrate > np.quantile(vrate, 0.8)
    assert np.mean(hr[fast]) > 3 * np.mean(hr[~fast])  # the rate's band is wide where the run moves fast
    inside_r, inside_e = np.abs(vy - vc) <= hr, np.abs(vy - vc) <= he
    assert 0.85 <= np.mean(inside_r) <= 0.95  # calibrated on a record like the validation one
    assert np.mean(inside_r[fast]) > np.mean(inside_e[fast]) + 0.2  # and covers the fast part the engine's misses
    assert np.mean(2 * hr) < np.mean(2 * he)  # with a narrower band on average


def test_factors_are_the_rescalings_of_the_band_that_would_meet_the_target(tmp_path: Any) -> None:
    u, y = _data(900)
    ens = ensemble_of([_net(0, (Y1, U1)), _net(1, (Y1, Y2, U1, U3), 5), _net(2, (Y1, U1, U3), 3)], combine="median")
    t = Target("toy", "", u[:600].reshape(-1, 1), y[:600], u[600:].reshape(-1, 1), y[600:], kind="two-experiment")
    interval, _ = calibrate(ens, t.u_est, t.y_est, RIDGE)
    doc = replace(ens, interval=interval).to_dict()
    f = features(ens, t)
    np.savez(tmp_path / "000.npz", **f)
    rows = [{"target": "toy", "seed": 0, "kept": {"fr_val": 0.99}, "median": None, "paper": {"fr_val": 0.99},
             "models": {"kept": doc}}]
    line = factors(rows, str(tmp_path))[2]
    assert line.startswith("| toy (0.9900) | ")
    got = line.split("| ")[2].strip(" |")
    f["yhalf"] = np.float64(ens.normalisation.y_half_range)
    make = VARIANTS["engine"](f)
    assert make is not None
    v = (f["val_y"], f["val_centre"], f["val_spread"], f["val_far"])
    ok = [c for c in FACTORS if 0.85 <= score(f, c * make(v))["coverage"] <= 0.97
          and score(f, c * make(v))["width_over_rms"] <= 4.0]
    assert ok, "the toy row has a rescaling that meets the target"
    assert got == f"{min(ok):.3f} - {max(ok):.3f}"
    lo, hi = (float(x) for x in got.split(" - "))
    assert score(f, hi * 1.1 * make(v))["coverage"] > 0.97 or score(f, hi * 1.1 * make(v))["width_over_rms"] > 4.0
