"""The daemon honours ``engine.selection``: "fr_est" (best free run on estimation, the default) or "fitness" (the
run's best pair, the paper's)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from streamid.wire.codec import SampleBatch
from streamid.daemon.config import StreamConfig, config_from_mapping
from streamid.online.window import WindowBuffer
from streamid.online.update import identify_window
from streamid.engine.identification import free_run_r2
from streamid.engine.validation import r2
from streamid.errors import ConfigError
from streamid.logs import bundled_log, read_log_arrays

BASE = StreamConfig(window_s=3.0, update_every_s=1.5, cold_generations=40, warm_generations=10, neurons=5,
                    max_lag_y=3, max_lag_u=3, seed=2, max_pending_windows=8)


def _windows(cfg: StreamConfig) -> list:
    log = read_log_arrays(bundled_log("mr_damper.mcap"))
    wb = WindowBuffer("mr", cfg.window_params())
    u, y = log.inputs["velocity_cm_s"], log.outputs["force_N"]
    for k, i in enumerate(range(0, 1500, 50)):
        wb.append(SampleBatch("mr", k, int(log.t_ns[i]), log.period_ns, None, {"velocity_cm_s": u[i : i + 50]},
                              {"force_N": y[i : i + 50]}))
    out = []
    while (w := wb.take()) is not None:
        out.append(w)
    return out


def test_fr_est_publishes_the_candidate_with_the_best_free_run_on_estimation() -> None:
    cfg_fit = dataclasses.replace(BASE, engine=(("selection", "fitness"),))
    # the online default's choice; without its long linear part (tests/test_online_long_linear.py), which with
    # these lags (<= 3) may extend the chosen network, so that the two choices are compared as such
    cfg_fr = dataclasses.replace(BASE, engine=(("long_linear", 0),))
    assert BASE.coea_config(cold=False).selection == "fr_est"
    assert dataclasses.replace(BASE, engine=(("de_f", 0.5),)).coea_config(cold=True).selection == "fr_est"
    wins = _windows(BASE)
    assert len(wins) >= 2
    w = wins[0]
    a = identify_window(w, cfg_fit, version=1)
    b = identify_window(w, cfg_fr, version=1)  # same seed, same run: only the choice differs
    assert a.kind == "identified" and b.kind == "identified"
    n_est = b.window_meta["n_estimation"]
    ue, ye = w.u[:n_est], w.y[:n_est, 0]
    fr_a, fr_b = free_run_r2([a.model, b.model], ue, ye)
    assert b.model.metrics["selection"] == "fr_est"
    assert b.model.metrics["selection_score"] == pytest.approx(fr_b, abs=1e-12)
    assert fr_b >= fr_a  # the best pair is among the candidates
    assert "selection" not in a.model.metrics
    # the published figures are those of the chosen model, on the held-out part
    uv, yv = w.u[n_est:], w.y[n_est:, 0]
    L = b.model.max_lag
    sim = b.model.simulate(uv, yv[:L])
    assert r2(yv[L:], sim[L:]) == pytest.approx(b.summary.metrics["r2_fr_val"], abs=1e-12)
    # and warm updates keep choosing that way
    c = identify_window(wins[1], cfg_fr, version=2, warm_state=b.state, warm_signature=b.signature)
    assert c.warm and c.model.metrics["selection"] == "fr_est"
    assert np.isfinite(c.summary.metrics["r2_fr_val"])


def test_selections_the_daemon_cannot_do_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"engine.selection must be one of \['fitness', 'fr_est'\].*'holdout_fr'"):
        dataclasses.replace(BASE, engine=(("selection", "holdout_fr"),))
    with pytest.raises(ConfigError, match="engine.selection"):
        config_from_mapping({"defaults": {"engine": {"selection": "holdout_fr"}}})
    cfg = config_from_mapping({"streams": {"mr": {"engine": {"selection": "fr_est"}}}})
    assert cfg.for_stream("mr").coea_config(cold=False).selection == "fr_est"
