"""Clear errors for bad data and bad settings (rule, accepted form, offending value)."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine import CoEAConfig, Coevolution
from streamid.engine.identification import identify
from streamid.errors import ConfigError, DataError

CFG = CoEAConfig(neurons=4, max_lag_y=3, max_lag_u=3, generations=2)


def _data(n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_named_with_sample(bad: float) -> None:
    u, y = _data()
    u[17] = bad
    with pytest.raises(DataError, match=r"u must contain only finite numbers.*sample 17"):
        Coevolution(u, y, CFG, 0)
    u, y = _data()
    y[5] = bad
    with pytest.raises(DataError, match=r"y must contain only finite.*sample 5"):
        identify(u, y, CFG, 0)


def test_constant_signals_zero_range() -> None:
    u, y = _data()
    with pytest.raises(DataError, match=r"output is constant.*min = max = 2\.5"):
        Coevolution(u, np.full_like(y, 2.5), CFG, 0)
    with pytest.raises(DataError, match=r"input 1 is constant"):
        Coevolution(np.column_stack([u, np.zeros_like(u)]), y, CFG, 0)


def test_too_few_samples_for_the_lags() -> None:
    u, y = _data(10)
    with pytest.raises(DataError, match=r"10 estimation samples are too few.*max lag 3.*at least max_lag \+ 2 \* neurons = 11"):
        Coevolution(u, y, CFG, 0)
    with pytest.raises(DataError, match="too few"):
        identify(u, y, CFG, 0)


def test_shapes() -> None:
    u, y = _data()
    with pytest.raises(DataError, match="same number of samples"):
        Coevolution(u[:-1], y, CFG, 0)
    with pytest.raises(DataError, match="one output"):
        Coevolution(u, np.column_stack([y, y]), CFG, 0)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("neurons", 0, r"neurons must be an integer in \[1, 1000\]; got 0"),
        ("population", 3, r"population must be an integer in \[4, 10000\]; got 3"),
        ("de_cr", 1.5, r"de_cr must be a number in \[0.0, 1.0\]; got 1.5"),
        ("de_f", 0.0, r"de_f must be a number in \(0.0, 2.0\]"),
        ("width_bounds", (0.0, 1.0), r"width_bounds must be a pair .* 0 < low < high; got \(0.0, 1.0\)"),
        ("generations", -1, "generations must be an integer >= 0"),
        ("selection", "vote", r"selection must be one of"),
        ("neurons", True, "neurons must be an integer"),
    ],
)
def test_config_errors(field: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        CoEAConfig(**{field: value})


def test_config_dict_round_trip_and_unknown_key() -> None:
    c = CoEAConfig.recommended()
    assert CoEAConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ConfigError, match=r"unknown CoEAConfig field\(s\) \['nuerons'\]"):
        CoEAConfig.from_dict({"nuerons": 3})


def test_rng_must_be_reproducible() -> None:
    u, y = _data()
    with pytest.raises(ConfigError, match="rng must be"):
        Coevolution(u, y, CFG, "seed")  # type: ignore[arg-type]
