"""Registry of simulated devices: names, timing, channels, seeding, errors."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.errors import ConfigError
from streamid.sim import ALIASES, DEVICES, Trace, device_names, get_device


def test_registry_contents() -> None:
    assert set(device_names()) == {"piezo", "mr_damper", "reactor", "bouc_wen"}
    assert get_device("piezo").rate_hz == pytest.approx(20_000.0)
    assert get_device("mrdamper") is DEVICES["mr_damper"]
    assert get_device("reactor").period_ns == 200_000_000
    assert get_device("mr_damper").period_ns == 5_000_000
    for alias, name in ALIASES.items():
        assert get_device(alias).name == name
    with pytest.raises(TypeError):
        DEVICES["x"] = DEVICES["piezo"]  # type: ignore[index]


@pytest.mark.parametrize("name", ["piezo", "mr_damper", "reactor", "bouc_wen"])
def test_each_device_simulates_its_minimum_record(name: str) -> None:
    dev = get_device(name)
    seconds = max(dev.min_seconds, 1.0)
    tr = dev.simulate_seconds(seconds, 5)
    n = dev.n_samples(seconds)
    assert isinstance(tr, Trace) and len(tr.y) == n
    assert tr.t_ns.dtype == np.int64 and tr.u.dtype == tr.y.dtype == np.float64
    assert tr.t_ns[0] == 0 and np.all(np.diff(tr.t_ns) == dev.period_ns)
    assert np.all(np.isfinite(tr.u)) and np.all(np.isfinite(tr.y)) and np.ptp(tr.y) > 0
    again = dev.simulate(n, np.random.default_rng(5))
    assert np.array_equal(again.y, tr.y)
    assert dev.input_name and dev.output_name and dev.input_unit and dev.output_unit


def test_errors_name_the_value() -> None:
    with pytest.raises(ConfigError, match="'laser'"):
        get_device("laser")
    with pytest.raises(ConfigError, match="at least"):
        get_device("piezo").n_samples(0.001)
    with pytest.raises(ConfigError, match="nan"):
        get_device("reactor").n_samples(float("nan"))
    with pytest.raises(ConfigError, match="Generator"):
        get_device("reactor").simulate_seconds(1.0, -3)  # type: ignore[arg-type]
