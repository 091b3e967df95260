"""Progress of one identification: every generation of every restart made in this process is reported."""

from __future__ import annotations

import numpy as np

from streamid.engine import identify
from streamid.engine.search.coevolution import Progress
from streamid.engine.search.parallel import EvalHelper
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
    cfg = DEFAULT.replace(neurons=5, generations=6, lag_search_neurons=3, restarts=3,
                          population=10, max_lag_y=3, max_lag_u=3)
    seen: list[Progress] = []
    res = identify(u, y, cfg, 0, callback=seen.append)
    per_run = 6 + 6  # the lag search stage and the second stage, each of `generations`
    gens = [p.generation for p in seen]
    assert len(seen) >= cfg.restarts * cfg.generations, gens  # every generation, not once per finished run
    assert gens == sorted(gens) and gens[-1] == per_run * cfg.restarts, gens
    assert {p.generations for p in seen} == {per_run * cfg.restarts}
    evals = [p.evaluations for p in seen]
    assert evals == sorted(evals) and evals[-1] == res.evaluations
    best = [p.best_fitness for p in seen]
    assert all(np.isfinite(best)) and min(best) > 0
    # then one report of the stage after the search: the kept model's choice (size, ensemble, refinement, interval)
    assert [p.stage for p in seen] == ["search"] * (len(seen) - 1) + ["choice"]


def test_cli_bar_moves_within_one_run_on_a_pipe() -> None:
    """`--progress always` on a pipe: one identification of 2 two-stage restarts redraws the bar many times, each
    time some generations further, not once per finished restart (the default --workers 2: in this process with the
    evaluation helper; where the helper is not supported, restarts go to processes and only --workers 1 does so)."""
    import re
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "streamid", "identify", "mr_damper", "--est", "2000", "--progress",
                        "always", "--json", "--restarts", "2", "--generations", "125", "--lag-search-neurons", "10",
                        *([] if EvalHelper.supported() else ["--workers", "1"])],
                       capture_output=True, timeout=120)  # bytes: text mode turns \r into \n
    stderr, stdout = p.stderr.decode(), p.stdout.decode()
    assert p.returncode == 0, stderr
    draws = re.findall(r"\ridentify \[[# ]{30}\] +([0-9.]+)% generation (\d+)/(\d+), (\d+) evaluations", stderr)
    gens = [int(g) for _, g, _, _ in draws]
    total = {int(t) for _, _, t, _ in draws}
    assert total == {500}, total  # 2 restarts x (125 lag-search + 125 final generations)
    inside = [g for g in gens if g % 250]  # not at the end of a restart
    assert len(draws) >= 6 and len(inside) >= 4, gens  # drawn between restarts' ends: it moves within a run
    assert gens == sorted(gens) and gens[-1] == 500 and float(draws[-1][0]) == 100.0, gens
    evals = [int(e) for *_, e in draws]
    assert evals == sorted(evals) and evals[-1] == __import__("json").loads(stdout)["runs"][0]["evaluations"]
    assert stderr.endswith("\n")  # the bar's line is ended
    # the stages after the search are said on the same line, in order (a long record spends seconds in them)
    choosing, validating = stderr.rfind("choosing the kept model"), stderr.rfind("validating the kept model")
    assert 0 < choosing < validating and choosing > stderr.rfind("generation 500/500"), stderr[-400:]
