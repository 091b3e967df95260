"""How many runs an identification makes: fewer when they agree, more when the record is half explained.

Pure rules over the runs already made (their ``score``: the estimation free-run R^2 of each run's
chosen candidate, ``-1e9`` when none is admissible) and the loop that makes the restarts in order.
:func:`~streamid.engine.identification.identify` owns the runs themselves.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from functools import partial
from typing import Any

from streamid.engine.fanout import fan_out
from streamid.engine.parallel import EvalHelper
from streamid.engine.settings import CoEAConfig

__all__ = ["repeats_agree", "report_after", "runs_until_agreed", "wants_more"]


def report_after(report: Callable[[list[dict[str, Any]]], None], made: list[dict[str, Any]],
                 rs: list[dict[str, Any]]) -> None:
    """Report the runs ``made`` before a batch together with the batch's ``rs``."""
    report(made + rs)


def repeats_agree(outs: list[dict[str, Any]], job: dict[str, Any], cfg: CoEAConfig) -> bool:
    """Whether ``job`` is a repeat not worth making: the runs already made with its configuration (neurons,
    lag space) include two whose selection scores are the best two, both above ``fallback_below`` (good,
    admissible fits), and within ``agree_tol`` of each other."""
    same = sorted(float(o["score"]) for o in outs
                  if (o["neurons"], o["max_lag"]) == (job["neurons"], job["max_lag"]))
    return len(same) >= 2 and same[-2] > max(-1e9, cfg.fallback_below) and same[-1] - same[-2] <= cfg.agree_tol


def wants_more(outs: list[dict[str, Any]], cfg: CoEAConfig) -> bool:
    """Whether ``cfg.more_restarts`` more runs are made after ``outs`` (:class:`CoEAConfig`, ``more_restarts``).

    Yes when the best run's score (a free-run R^2: never with ``selection="fitness"``) is in ``(0, more_below)``: the runs explain part of the estimation
    record but leave more than ``1 - more_below`` of its variance, which is where the estimation data
    tell the runs apart least reliably, so the choice (and the ensembles of the best runs) gains most
    from a larger field.  Not when no run explains anything (best ``<= 0``: more runs of the same
    networks measured no better there; the ``fallback_neurons`` runs are the remedy), nor when one
    explains most of it (more runs measured worse on Bouc-Wen: more candidates, the same data to
    choose by).
    """
    if not cfg.more_restarts or not outs or cfg.selection == "fitness":  # (then a score is not an R^2)
        return False
    best = max(float(o["score"]) for o in outs)
    return 0.0 < best < cfg.more_below


def runs_until_agreed(jobs: list[dict[str, Any]], cfg: CoEAConfig, executor: Executor | None,
                      helper: EvalHelper | None, report: Callable[[list[dict[str, Any]]], None],
                      run: Callable[..., dict[str, Any]]) -> tuple[list[dict[str, Any]], list[int]]:
    """The restarts in order, ``cfg.workers`` at a time, each skipped when :func:`repeats_agree`;
    ``run(job, helper)`` makes one. Returns the runs made and the indices of the jobs skipped."""
    outs: list[dict[str, Any]] = []
    skipped: list[int] = []
    i = 0
    while i < len(jobs):
        chunk: list[int] = []
        while i < len(jobs) and len(chunk) < max(1, cfg.workers):
            if repeats_agree(outs, jobs[i], cfg):
                skipped.append(i)
            else:
                chunk.append(i)
            i += 1
        if chunk:
            made = list(outs)
            outs = made + fan_out(run, [jobs[k] for k in chunk], cfg.workers, executor=executor,
                                  helper=helper, on_result=partial(report_after, report, made))
    return outs, skipped
