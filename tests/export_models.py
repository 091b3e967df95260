"""Models of every kind the engine writes, for the export tests (tests/test_export_*.py), and a validation record.

Built directly (as tests/test_predictor.py builds them) with small, stable parameters, so each is quick and
its free run stays bounded; ``identified`` is a real identification on a simulated reactor.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from streamid.model.ensemble import ensemble_of
from streamid.model.narx import Model
from streamid.model.regressors import Normalisation, Regressor

PERIOD_NS = 10_000_000  # 10 ms
INPUTS = ("force_N", "valve")


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
