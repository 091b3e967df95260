"""Progress of one identification: every generation of every restart made in this process is reported."""

from __future__ import annotations

import numpy as np

from streamid.engine import identify
from streamid.engine.coevolution import Progress
from streamid.engine.settings import DEFAULT


def _narx(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2])
    return u, y


def test_restarts_in_process_report_every_generation() -> None:
    u, y = _narx(300, 1)
    cfg = DEFAULT.replace(neurons=5, generations=6, lag_search_neurons=3, lag_search_generations=4, restarts=3,
                          population=10, max_lag_y=3, max_lag_u=3, workers=1)
    seen: list[Progress] = []
    res = identify(u, y, cfg, 0, callback=seen.append)
    per_run = 6 + 4
    gens = [p.generation for p in seen]
    assert len(seen) >= cfg.restarts * cfg.generations, gens  # every generation, not once per finished run
    assert gens == sorted(gens) and gens[-1] == per_run * cfg.restarts, gens
    assert {p.generations for p in seen} == {per_run * cfg.restarts}
    evals = [p.evaluations for p in seen]
    assert evals == sorted(evals) and evals[-1] == res.evaluations
    best = [p.best_fitness for p in seen]
    assert all(np.isfinite(best)) and min(best) > 0
