"""Models that know when they do not know: median ensembles, the free-run interval and the estimation domain."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from streamid.engine import DEFAULT, identify
from streamid.engine.choice.calibration import calibrate
from streamid.engine.settings import RIDGE
from streamid.errors import DataError, ModelFormatError
from streamid.model import Model
from streamid.model.domain import domain_text, excess, far_from_domain, outside, outside_share
from streamid.model.ensemble import EnsembleModel, ensemble_of
from streamid.model.uncertainty import (BEYOND, LEVELS, Band, Interval, band_coverage, conformal_quantiles, interval_report,
                                        interval_text, member_spread)
from streamid.sim import simulate_mr_damper
from test_engine_ensemble import NORM, U1, U3, Y1, _data, _net

def test_conformal_quantiles_are_the_finite_sample_order_statistics() -> None:
    scores = np.arange(1.0, 100.0)  # 99 scores 1..99: level 0.9 takes the ceil(100 * 0.9) = 90th smallest
    assert conformal_quantiles(scores, (0.5, 0.9, 0.99)) == (50.0, 90.0, 99.0)
    assert conformal_quantiles(np.arange(1.0, 21.0), (0.99,)) == (20.0,)  # beyond n: the largest score
    with pytest.raises(DataError, match="at least 20 calibration samples; got 5"):
        conformal_quantiles(np.ones(5))


def test_a_median_ensemble_is_its_own_format_and_moves_little_with_one_wild_member() -> None:
    ms = [_net(0, (Y1, U1)), _net(1, (Y1, U1, U3), 5), _net(2, (Y1, U1), 3)]
    wild = replace(ms[2], weights=ms[2].weights * 1000.0)
    med, mean = ensemble_of([*ms[:2], wild], combine="median"), ensemble_of([*ms[:2], wild])
    u, y = _data()
    paths = np.array([m.simulate(u, y) for m in (*ms[:2], wild)])
    L = med.max_lag
    assert np.allclose(med.simulate(u, y)[L:], np.median(paths, axis=0)[L:])
    assert np.allclose(mean.simulate(u, y)[L:], np.mean(paths, axis=0)[L:])
    osa = np.array([m.predict_osa(u, y) for m in (*ms[:2], wild)])
    assert np.allclose(med.predict_osa(u, y)[L:], np.median(osa, axis=0)[L:])
    doc = json.loads(med.to_json())
    assert doc["format"] == "streamid.model/6" and doc["combine"] == "median" and "median_i" in doc["formula"]
    back = Model.from_json(json.dumps(doc))
    assert isinstance(back, EnsembleModel) and back.combine == "median"
    assert np.array_equal(back.simulate(u, y), med.simulate(u, y))
    assert json.loads(mean.to_json())["format"] == "streamid.model/3" and "combine" not in json.loads(mean.to_json())
    with pytest.raises(ModelFormatError, match="'combine' must be 'median' in a streamid.model/6"):
        Model.from_dict({**doc, "combine": "mean"})
    with pytest.raises(ModelFormatError, match="combine must be one of mean, median; got 'max'"):
        ensemble_of(ms, combine="max")


def test_the_band_is_the_quantile_times_the_scale_and_the_members_spread() -> None:
    ms = [_net(0, (Y1, U1)), _net(1, (Y1, U1, U3), 5), _net(2, (Y1, U1), 3)]
    interval = Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100)
    ens = replace(ensemble_of(ms, combine="median"), interval=interval)
    u, y = _data()
    band = ens.simulate(u, y, interval=0.9)
    assert isinstance(band, Band) and np.array_equal(band.y, ens.simulate(u, y))
    spread = member_spread(ens.member_paths(u, y))
    L = ens.max_lag
    assert np.allclose((band.upper - band.y)[L:], 1.5 * (0.1 + spread[L:]))
    assert np.array_equal(band.lower[:L], band.y[:L]) and np.array_equal(band.upper[:L], band.y[:L])
    wider = ens.simulate(u, y, interval=0.99)
    assert np.all(wider.upper[L:] > band.upper[L:])
    single = replace(ms[0], interval=interval)
    one = single.simulate(u, y, interval=0.5)
    assert np.allclose((one.upper - one.y)[single.max_lag:], 0.5 * 0.1)  # one network: the scale alone
    back = Model.from_json(ens.to_json())
    assert back.interval == interval
    rep = interval_report(single, u, y)  # a single network's band from a free run the caller has: the same figures
    assert rep is not None and rep == interval_report(single, u, y, free_run=single.simulate(u, y))
    with pytest.raises(DataError, match="interval level must be one of 0.5, 0.8, 0.9, 0.95, 0.99 .* got 0.42"):
        ens.simulate(u, y, interval=0.42)
    with pytest.raises(DataError, match="carries no prediction interval"):
        ms[0].simulate(u, y, interval=0.9)
    with pytest.raises(ModelFormatError, match="model field 'interval' must be an object with levels"):
        Model.from_dict({**json.loads(single.to_json()), "interval": {"levels": [0.9], "quantiles": [-1.0],
                                                                      "scale": 0.1, "samples": 3}})


def test_coverage_counts_the_samples_inside_the_band() -> None:
    y = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    band = Band(np.zeros(5), np.full(5, -0.5) + np.arange(5), np.full(5, 0.5) + np.arange(5))
    got = band_coverage(y, band, start=1)
    assert got["coverage"] == 0.75 and got["width"] == 1.0
    assert math.isclose(got["width_over_std"], 1.0 / float(np.std(y[1:])))
    assert "does not know this record" in interval_text({"level": 0.9, **got}, "validation")
    assert "does not know" not in interval_text({"level": 0.9, "coverage": 0.9, "width": 1.0, "width_over_std": 0.1}, "x")


def test_the_report_says_what_makes_the_band_wide() -> None:
    """``assess`` (``validate``, ``identify``'s validation) splits the band's mean half-width into its terms: the
    error's scale, the networks' disagreement, the distance beyond the domain; the line names the parts that count."""
    from streamid.engine.validation import assess
    from streamid.model.uncertainty import coverage_figures

    ms = [_net(0, (Y1, U1)), _net(1, (Y1, U1, U3), 5), _net(2, (Y1, U1), 3)]
    interval = Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100, beyond=BEYOND)
    ens = replace(ensemble_of(ms, combine="median"), interval=interval)
    u, y = _data()
    L = ens.max_lag
    rep = assess(ens, u, y).interval
    assert rep is not None
    spread = member_spread(ens.member_paths(u, y))[L:]
    past = BEYOND * far_from_domain(ens, u, ens.simulate(u, y))[L:]
    total = 0.1 + float(np.mean(spread)) + float(np.mean(past))
    want = {"scale": 0.1 / total, "spread": float(np.mean(spread)) / total, "beyond": float(np.mean(past)) / total}
    assert rep["width_from"] == pytest.approx(want, rel=1e-9) and want["spread"] > 0.01
    assert math.isclose(rep["width"], 2 * 1.5 * total, rel_tol=1e-9)  # the parts are the width's own terms
    text = interval_text(rep, "validation")
    assert f"its width: {100 * want['scale']:.0f} % from the error's scale, {100 * want['spread']:.0f} % from the " \
           "networks' disagreement" in text
    single = replace(ms[0], interval=replace(interval, beyond=0.0))
    one = assess(single, u, y).interval  # one network, a band without the growth past the domain: the scale alone
    assert one is not None and one["width_from"] == {"scale": 1.0, "spread": 0.0, "beyond": 0.0}
    assert "; its width: 100 % from the error's scale; under 80 %: the model does not know" in interval_text(one, "v")
    far = {"level": 0.9, **coverage_figures(0.95, 3.0, 1.0, (0.1, 0.0, 0.9))}  # mostly beyond the domain
    assert interval_text(far, "x").endswith("; its width: 10 % from the error's scale, 90 % from the distance beyond "
                                            "the estimation domain")
    assert "width_from" not in coverage_figures(0.5, math.inf, 1.0, (0.1, math.inf, 0.0))  # a run that diverged
    assert "its width" not in interval_text({"level": 0.9, "coverage": 0.9, "width": 1.0, "width_over_std": 0.1}, "x")


def test_the_domain_is_each_regressors_estimation_range() -> None:
    net = _net(0, (Y1, U3))
    u = np.zeros((10, 1))
    y = np.zeros(10)
    assert not outside(NORM, net.regressors, u, y).any() and outside_share(net, u, y) == 0.0
    u[4, 0] = 1.5  # beyond u_high = 1: the regressor u(t-3) is outside at t = 7 only
    assert np.flatnonzero(outside(NORM, net.regressors, u, y)).tolist() == [7]
    y[8] = -2.5  # beyond y_low = -2: y(t-1) is outside at t = 9
    assert np.flatnonzero(outside(NORM, net.regressors, u, y)).tolist() == [7, 9]
    assert np.flatnonzero(outside(NORM, net.regressors, u)).tolist() == [7]  # free run: the inputs alone
    assert outside_share(net, u, y) == pytest.approx(2 / 7)  # of the samples from max_lag 3 on
    assert "28.6 % of the validation samples" in domain_text(2 / 7, "validation")
    # how far beyond, in half-spans of each range: u's is [-1, 1] (half-span 1), y's [-2, 2] (half-span 2)
    far = excess(NORM, net.regressors, u, y)
    assert far.tolist() == [0.0] * 7 + [0.5, 0.0, 0.25]
    assert np.array_equal(far > 0, outside(NORM, net.regressors, u, y))


def test_beyond_its_domain_the_band_grows_with_how_far_and_an_older_document_keeps_its_band() -> None:
    net = _net(0, (Y1, U3))
    _, y = _data()
    u = np.random.default_rng(7).uniform(-0.9, 0.9, (len(y), 1))
    u[200:260] *= 1.8  # the input leaves its estimation range [-1, 1] there
    grown = replace(net, interval=Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100, beyond=BEYOND))
    before = replace(grown, interval=replace(grown.interval, beyond=0.0))  # a document without the rule
    b1, b0 = grown.simulate(u, y, interval=0.9), before.simulate(u, y, interval=0.9)
    far = far_from_domain(grown, u, b1.y)
    L = net.max_lag
    assert np.array_equal(b1.y, b0.y) and np.allclose((b0.upper - b0.y)[L:], 1.5 * 0.1)
    assert np.allclose((b1.upper - b1.y)[L:], 1.5 * (0.1 + BEYOND * far[L:]))
    assert np.array_equal(far > 0, outside(NORM, net.regressors, u, b1.y))  # where a regressor is outside
    assert np.any(far[203:263] > 0.1) and not np.any(outside(NORM, net.regressors, u)[L:200])
    assert np.allclose(far, excess(NORM, net.regressors, u.reshape(len(u), -1), b1.y) * 2.0)  # y half-range 2
    d = json.loads(grown.to_json())["interval"]
    assert d["beyond"] == BEYOND and "beyond" in d["band"]
    assert Model.from_json(grown.to_json()).interval == grown.interval
    old = json.loads(before.to_json())
    assert "beyond" not in old["interval"] and Model.from_dict(old).interval == before.interval
    with pytest.raises(ModelFormatError, match="beyond"):
        Model.from_dict({**old, "interval": {**old["interval"], "beyond": -1.0}})


def test_identify_calibrates_an_interval_on_held_out_data_and_it_covers_the_next_record() -> None:
    est = simulate_mr_damper(3000, 1)
    val = simulate_mr_damper(3000, 2)  # another record of the same excitation (another seed)
    cfg = DEFAULT.replace(generations=15, restarts=2, neurons=10, lag_search_neurons=0, more_restarts=0)
    model = identify(est.u, est.y, cfg, 0).model
    cal = model.metrics["calibration"]
    assert model.interval is not None and model.interval.samples == cal["samples"] == 1500
    assert cal["scale"] > 0 and cal["r2_fr_held_out"] is not None
    rep = interval_report(model, val.u.reshape(-1, 1), val.y)
    assert rep is not None and 0.75 <= rep["coverage"] <= 1.0  # a 90 % band on a record of the same kind
    assert rep["width_over_std"] < 2.0  # and not uselessly wide
    assert Model.from_json(model.to_json()).interval == model.interval


def test_no_interval_is_made_from_too_few_samples_or_a_diverging_half() -> None:
    u, y = _data(30)
    interval, why = calibrate(_net(0, (Y1, U1)), u.reshape(-1, 1), y, RIDGE)
    assert interval is None and "too few samples to hold out (30" in why["reason"]


def test_the_predictor_serves_the_median_its_band_and_whether_it_is_in_domain() -> None:
    from streamid.model import Predictor

    ms = [_net(0, (Y1, U1)), _net(1, (Y1, U1, U3), 5), _net(2, (Y1, U1), 3)]
    interval = Interval(LEVELS, (0.5, 1.0, 1.5, 2.0, 3.0), 0.1, 100)
    ens = replace(ensemble_of(ms, combine="median"), interval=interval)
    u, y = _data(60)
    p = Predictor(ens)
    for t in range(40):
        p.learn_one(float(u[t]), float(y[t]))
    want = ens.predict_osa(np.append(u[:41], 0.0), np.append(y[:41], 0.0))[40]
    assert p.predict_one() == pytest.approx(want, rel=1e-12, abs=1e-12)
    band = p.forecast(u[40:50], interval=0.9)
    L = ens.max_lag  # the forecast starts from the newest max_lag measured samples
    whole = ens.simulate(u[40 - L:50], y[40 - L:40], interval=0.9)
    assert np.allclose(band.y, whole.y[L:]) and np.allclose(band.upper, whole.upper[L:])
    assert np.all(band.upper > band.y) and np.all(band.lower < band.y)
    assert p.in_domain() and p.in_domain(0.5)
    p.learn_one(1.7, float(y[40]))  # an input beyond the estimation range (u_high = 1): u(t-1) is outside next
    assert not p.in_domain()
