"""The champion/challenger rule of streamid.online.acceptance, branch by branch, on hand-made outcomes."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from streamid.online.acceptance import decide
from streamid.online.stream_config import StreamConfig
from streamid.online.summary import ValidationSummary
from streamid.online.update import Outcome


def _outcome(fr: float, osa: float, champ: dict[str, float] | None, model: Any = "m") -> Outcome:
    n = 5
    summary = ValidationSummary({"r2_fr_val": fr, "r2_osa_val": osa}, np.zeros(n), np.zeros(n))
    return Outcome("identified", model=model, summary=summary, champion_metrics=champ)


CFG = StreamConfig()  # floors 0.5 / 0.5, margin 0.005


def test_first_valid_challenger_is_accepted_and_an_invalid_one_never() -> None:
    d = decide(_outcome(0.9, 0.95, None), CFG, 0)
    assert (d.accepted, d.code) == (True, "first")
    d = decide(_outcome(0.4, 0.95, None), CFG, 0)
    assert (d.accepted, d.code) == (False, "validation") and "min_r2_fr 0.5" in d.reason
    d = decide(_outcome(float("nan"), 0.95, None), CFG, 0)
    assert (d.accepted, d.code) == (False, "validation")


def test_the_margin_decides_against_a_valid_champion() -> None:
    champ = {"r2_fr_val": 0.90, "r2_osa_val": 0.95}
    assert decide(_outcome(0.906, 0.95, champ), CFG, 3).code == "better"
    d = decide(_outcome(0.903, 0.95, champ), CFG, 3)
    assert (d.accepted, d.code) == (False, "not_better") and "margin 0.005" in d.reason
    assert d.champion == {"version": 3, "r2_fr_val": 0.90, "r2_osa_val": 0.95}


def test_an_invalid_champion_yields_to_any_better_valid_challenger() -> None:
    champ = {"r2_fr_val": 0.90, "r2_osa_val": 0.40}  # its OSA R^2 fell below the floor 0.5 on current data
    d = decide(_outcome(0.902, 0.95, champ), CFG, 2)  # within the margin, yet it replaces an invalid champion
    assert (d.accepted, d.code) == (True, "champion_invalid")
    assert decide(_outcome(0.89, 0.95, champ), CFG, 2).code == "not_better"  # not better at all
    assert decide(_outcome(0.44, 0.95, champ), CFG, 2).code == "validation"  # below the floor itself
    assert decide(_outcome(0.9, 0.95, None), CFG, 2).code == "champion_inapplicable"


@pytest.mark.parametrize("champion_fr", [0.99, 0.5, -3.0])
def test_margin_minus_one_accepts_every_valid_challenger_however_much_worse(champion_fr: float) -> None:
    """R^2 is unbounded below, so 'up to 1 worse' would not be 'every': -1 is documented as every valid one."""
    cfg = StreamConfig(challenger_margin=-1.0, min_r2_fr=-1e9, min_r2_osa=-1e9)
    d = decide(_outcome(-0.9, 0.1, {"r2_fr_val": champion_fr, "r2_osa_val": 0.9}), cfg, 4)
    assert (d.accepted, d.code) == (True, "every")
    assert "challenger_margin -1" in d.reason and d.champion is not None and d.champion["version"] == 4
    # still never an invalid one
    d = decide(_outcome(float("inf"), 0.1, {"r2_fr_val": champion_fr, "r2_osa_val": 0.9}), cfg, 4)
    assert (d.accepted, d.code) == (False, "validation")
    # and just above -1 the margin rule applies again
    near = StreamConfig(challenger_margin=-0.999, min_r2_fr=-1e9, min_r2_osa=-1e9)
    assert decide(_outcome(-0.9, 0.1, {"r2_fr_val": 0.99, "r2_osa_val": 0.9}), near, 4).code == "not_better"


def test_a_stream_is_degraded_by_its_champion_on_current_data_not_by_one_failing_challenger() -> None:
    from streamid.online.acceptance import degraded_after

    valid, poor = {"r2_fr_val": 0.90, "r2_osa_val": 0.95}, {"r2_fr_val": 0.14, "r2_osa_val": 0.95}
    # a challenger below the floor while a valid champion serves: healthy (the refusal is counted, not a state)
    d = decide(_outcome(0.4992, 0.95, valid), CFG, 6)
    assert (d.accepted, d.code) == (False, "validation") and degraded_after(d, CFG) == ""
    # ... and with a champion that fails on the same data: degraded, saying both
    d = decide(_outcome(-3.06, 0.95, poor), CFG, 6)
    why = degraded_after(d, CFG)
    assert why is not None and "min_r2_fr 0.5" in why and "champion v6 is not valid on the same data" in why
    assert "R² FR 0.1400" in why
    d = decide(_outcome(0.4, 0.9, {"r2_fr_val": float("nan"), "r2_osa_val": 0.95}), CFG, 2)
    assert "FR not finite" in (degraded_after(d, CFG) or "")
    # a champion kept against a valid challenger: healthy
    d = decide(_outcome(0.903, 0.95, valid), CFG, 3)
    assert d.code == "not_better" and degraded_after(d, CFG) == ""
    # no champion to judge, or an accepted model: the rule says nothing (the identifier keeps its own reason)
    assert degraded_after(decide(_outcome(0.4, 0.95, None), CFG, 0), CFG) is None
    assert degraded_after(decide(_outcome(0.95, 0.99, valid), CFG, 3), CFG) is None
