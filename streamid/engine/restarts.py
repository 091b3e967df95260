"""How many runs an identification makes: more when the record is half explained.

A pure rule over the runs already made (their ``score``: the estimation free-run R^2 of each run's
chosen candidate, ``-1e9`` when none is admissible). :func:`~streamid.engine.identification.identify`
owns the runs themselves.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from streamid.engine.settings import MORE_BELOW, CoEAConfig

__all__ = ["report_after", "wants_more"]


def report_after(report: Callable[[list[dict[str, Any]]], None], made: list[dict[str, Any]],
                 rs: list[dict[str, Any]]) -> None:
    """Report the runs ``made`` before a batch together with the batch's ``rs``."""
    report(made + rs)


def wants_more(outs: list[dict[str, Any]], cfg: CoEAConfig) -> bool:
    """Whether ``cfg.more_restarts`` more runs are made after ``outs`` (:class:`CoEAConfig`, ``more_restarts``).

    Yes when the best run's score (a free-run R^2: never with ``selection="fitness"``) is in ``(0, MORE_BELOW)``: the runs explain part of the estimation
    record but leave more than ``1 - MORE_BELOW`` of its variance, which is where the estimation data
    tell the runs apart least reliably, so the choice (and the ensembles of the best runs) gains most
    from a larger field.  Not when no run explains anything (best ``<= 0``: more runs of the same
    networks measured no better there; the ``fallback_neurons`` runs are the remedy), nor when one
    explains most of it (more runs measured worse on Bouc-Wen: more candidates, the same data to
    choose by).
    """
    if not cfg.more_restarts or not outs or cfg.selection == "fitness":  # (then a score is not an R^2)
        return False
    best = max(float(o["score"]) for o in outs)
    return 0.0 < best < MORE_BELOW
