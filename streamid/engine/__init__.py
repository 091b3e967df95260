"""The identification engine: coevolutionary RBF-NARX (see the modules for the method's details).

``identify`` (one identification, possibly several runs), ``Coevolution`` (one
steppable run with exportable ``CoEAState`` for warm starts), ``Model`` (prediction,
free run, ``streamid.model/1`` JSON; ``EnsembleModel``: the mean of several networks, ``/3``), ``validate`` / ``r2`` / ``correlation_tests``,
``EvalHelper`` (a helper process evaluating half of every population batch: the second core),
``warm_up_kernels`` (compile or load the compiled free-run loops before time-bound work).
"""

from __future__ import annotations

from streamid.engine.coevolution import CoEAState, Coevolution, Progress
from streamid.engine.settings import DEFAULT, PAPER, CoEAConfig
from streamid.engine.identify import Result, RunSummary, identify
from streamid.engine.model import MODEL_FORMAT, Model
from streamid.engine.ensemble import EnsembleModel
from streamid.engine.parallel import EvalHelper
from streamid.engine._kernels import warm_up as warm_up_kernels
from streamid.engine.validation import CorrelationReport, ValidationReport, correlation_tests, r2, validate

__all__ = [
    "CoEAConfig",
    "CoEAState",
    "Coevolution",
    "CorrelationReport",
    "DEFAULT",
    "EnsembleModel",
    "EvalHelper",
    "MODEL_FORMAT",
    "Model",
    "PAPER",
    "Progress",
    "Result",
    "RunSummary",
    "ValidationReport",
    "correlation_tests",
    "identify",
    "r2",
    "validate",
    "warm_up_kernels",
]
