"""Models of every kind the engine writes, for the export tests (tests/test_export_*.py), and a validation record.

Built directly (as tests/test_predictor.py builds them) with small, stable parameters, so each is quick and
its free run stays bounded; ``identified`` is a real identification on a simulated reactor.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from streamid.model.domain import outside
from streamid.model.ensemble import ensemble_of
from streamid.model.narx import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.model.uncertainty import BEYOND, LEVELS, Interval, member_spread

PERIOD_NS = 10_000_000  # 10 ms
INPUTS = ("force_N", "valve")
#: A 90 % interval (and the others a model carries) as a calibration would make it: q_0.9 = 1.7, scale 0.05.
INTERVAL = Interval(LEVELS, (0.7, 1.3, 1.7, 2.1, 2.9), 0.05, 200)
#: The same, growing beyond the estimation domain as intervals are calibrated now (``beyond``; INTERVAL: as a
#: document written before that rule, which an export must still reproduce).
INTERVAL_BEYOND = replace(INTERVAL, beyond=BEYOND)


def net(regs: list[tuple[str, int, int]], *, linear: str = "", seed: int = 0, output: str = "pos_mm",
        neurons: int = 5) -> Model:
    """A network over (signal, input index, lag) regressors of the two inputs; ``linear``: "" none, "own" on its
    regressors, "long" a long linear part of its own (lags up to 12)."""
    k = len(regs)
    rng = np.random.default_rng(seed)
    long_regs = tuple(Regressor(s, i, lag) for s, i, lag in (("y", 0, 1), ("y", 0, 7), ("u", 1, 4), ("u", 0, 12)))
    lin = {"": None, "own": rng.normal(0, 0.1, k + 1), "long": rng.normal(0, 0.1, len(long_regs) + 1)}[linear]
    return Model(regressors=tuple(Regressor(s, i, lag) for s, i, lag in regs),
                 centres=rng.uniform(-0.6, 0.6, (neurons, k)), widths=rng.uniform(0.6, 1.4, neurons),
                 weights=rng.normal(0, 0.4, neurons),
                 normalisation=Normalisation((-2.0, -1.0), (2.0, 3.0), -3.0, 2.0), linear=lin,
                 linear_regressors=long_regs if linear == "long" else None, input_names=INPUTS, output_name=output,
                 window={"period_ns": PERIOD_NS, "n_samples": 1000})


def kinds() -> dict[str, Model]:
    """One model of every kind, by a short name."""
    a = net([("y", 0, 1), ("u", 0, 1), ("u", 1, 3), ("y", 0, 2)])
    b = net([("u", 1, 2), ("y", 0, 3), ("u", 0, 5)], linear="own", seed=1)
    c = net([("y", 0, 1), ("u", 0, 2)], linear="long", seed=2)
    d = net([("y", 0, 1), ("u", 0, 0), ("u", 1, 1)], linear="own", seed=3)  # force_N(t): a direct term
    win = {"period_ns": PERIOD_NS, "n_samples": 1000}
    return {
        "network": a,
        "linear": b,
        "long_linear": c,
        "direct": d,
        "ensemble": ensemble_of([a, b, d], window=win),
        "ensemble_long_linear": ensemble_of([c, a], window=win),
        # the per-sample median of 4 (the mean of the middle two) and of 3 networks, with the 90 % band
        "median": ensemble_of([a, b, d, c], combine="median", window=win, interval=INTERVAL),
        "median_odd": ensemble_of([b, c, a], combine="median", window=win, interval=INTERVAL_BEYOND),
        "network_band": replace(a, interval=INTERVAL_BEYOND),  # a single network's band: q_0.9 * (scale + far)
        "network_band_before": replace(a, interval=INTERVAL),  # as written before the band grew beyond the domain
    }


def second_output() -> Model:
    """A model of another output of the same inputs (with a direct term in ``valve``)."""
    return replace(net([("y", 0, 1), ("u", 1, 0), ("u", 0, 2), ("y", 0, 4)], linear="own", seed=9,
                       output="temp_C"))


def record(n: int = 600, seed: int = 5) -> np.ndarray:
    """A validation record of the two inputs: steps and noise across (and a little beyond) their ranges."""
    rng = np.random.default_rng(seed)
    steps = np.repeat(rng.uniform(-2.2, 2.2, (n // 20 + 1, 2)), 20, axis=0)[:n]
    return steps + rng.normal(0, 0.2, (n, 2)) * np.array([1.0, 2.0]) + np.array([0.0, 1.0])


def check_added_outputs(m: Model, u: np.ndarray, initial: float, x: dict[str, np.ndarray]) -> None:
    """The export's ``<output>_lower``/``_upper`` equal the 90 % band of ``Model.simulate`` (to 1e-9 of the
    output's range; present only when the model carries an interval) and ``<output>_in_domain`` is 1.0 exactly
    where :func:`streamid.model.domain.outside` finds every regressor within the estimation range."""
    name, span = m.output_name, m.normalisation.y_high - m.normalisation.y_low
    y_init = np.full(m.max_lag, initial)
    if m.interval is None:
        assert f"{name}_lower" not in x and f"{name}_upper" not in x
        y = m.simulate(u, y_init)
    else:
        band = m.simulate(u, y_init, interval=0.9)
        y = band.y
        assert np.max(np.abs(x[f"{name}_lower"] - band.lower)) <= 1e-9 * span, name
        assert np.max(np.abs(x[f"{name}_upper"] - band.upper)) <= 1e-9 * span, name
        width = band.upper - band.lower
        assert np.all(width[m.max_lag:] > 0) and np.all(width[: m.max_lag] == 0)
        if len(getattr(m, "members", ())) > 1:  # the members' spread widens it beyond q * scale somewhere
            assert np.max(width) > 2 * m.interval.quantile(0.9) * m.interval.scale * 1.5
    regs = {r for net in getattr(m, "members", (m,)) for r in (*net.regressors, *(net.linear_regressors or ()))}
    flags = outside(m.normalisation, sorted(regs, key=lambda r: (r.signal, r.index, r.lag)), u, y)
    if m.interval is not None:  # beyond the domain the band grows (beyond > 0), and only there
        paths = m.member_paths(u, y_init)
        inner = 2 * m.interval.quantile(0.9) * (m.interval.scale + member_spread(paths))
        inner[: m.max_lag] = 0.0
        grown = width > inner * (1 + 1e-9) + 1e-12 * span
        assert not np.any(grown & ~flags)
        assert np.any(grown) == (m.interval.beyond > 0), name
    assert np.array_equal(x[f"{name}_in_domain"], np.where(flags, 0.0, 1.0)), name
    assert 0.05 < np.mean(flags) < 0.95  # the record leaves the domain and comes back: both values tested
