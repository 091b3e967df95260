"""benchmarks.calibration_study: its 'engine' variant is the engine's calibration, to the quantile and the band."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from benchmarks.calibration_study import VARIANTS, conformal, features
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
