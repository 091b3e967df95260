"""An online update's refinement (issue 37's judged refinement, the online default since 2026-11-28)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from streamid import OnlineIdentifier, StreamConfig
from streamid.online.stream_config import ONLINE_REFINE
from streamid.sim.mrdamper import MRDamperParams, simulate_mr_damper

N = 6000  # 3 s of the simulated MR damper at 2 kHz: one window


def _update(seed: int, refine: int | None) -> Any:
    _, u, y = simulate_mr_damper(N, seed, params=MRDamperParams(period_ns=500_000))
    engine = () if refine is None else (("refine_iterations", refine),)
    cfg = StreamConfig(window_samples=N, update_every_samples=N, cold_generations=60, seed=seed, engine=engine)
    ident = OnlineIdentifier(cfg, stream="d")
    ident.learn_many(np.arange(N, dtype=np.int64) * 500_000, u, y, inputs=["v"], outputs=["f"])
    (up,) = ident.update_all()
    assert up.model is not None, up
    return up


def test_the_online_default_refines_and_a_setting_turns_it_off() -> None:
    assert ONLINE_REFINE == 10
    assert StreamConfig().coea_config(cold=True).refine_iterations == ONLINE_REFINE
    assert StreamConfig(engine=(("refine_iterations", 0),)).coea_config(cold=False).refine_iterations == 0


@pytest.mark.parametrize("seed", [1, 3])  # measured: seed 1's refinement held on the held-out half, seed 3's did not
def test_an_update_is_refined_only_when_its_held_out_half_gains(seed: int) -> None:
    up, off = _update(seed, None), _update(seed, 0)  # the default, and the refinement off
    ev = up.model.metrics["refinement"]
    assert "refinement" not in off.model.metrics
    np.testing.assert_array_equal(up.model.centres, off.model.centres)  # the same run (the refinement draws nothing)
    held = ev["held_out"]
    n_est = N - len(up.outcome.y_val)  # judged on the second half of the estimation part, never the validation's
    assert held["samples"] == n_est - n_est // 2 and held["r2_fr_before"] is not None, ev
    if seed == 1:
        assert ev["taken"] and held["r2_fr_after"] > held["r2_fr_before"], ev
        assert ev["r2_fr_est_after"] > ev["r2_fr_est_before"] and not np.array_equal(up.model.weights, off.model.weights)
    else:
        assert not ev["taken"] and held["r2_fr_after"] <= held["r2_fr_before"], ev
        assert "no gain on the held-out second half" in ev["reason"]
        np.testing.assert_array_equal(up.model.weights, off.model.weights)  # the model as the run left it
