"""The identification engine: coevolutionary RBF-NARX (see the modules for the method's details).

``identify`` (one identification, possibly several runs), ``Coevolution`` (one
steppable run with exportable ``CoEAState`` for warm starts), ``Model`` (prediction,
free run, ``streamid.model/1`` JSON; ``EnsembleModel``: the mean of several networks, ``/3``), ``validate`` / ``assess`` (a model on a record it never saw) / ``r2`` / ``correlation_tests``,
``EvalHelper`` (a helper process evaluating half of every population batch: the second core),
``warm_up_kernels`` (compile or load the compiled free-run loops before time-bound work).

Every name is imported on first use: ``streamid.engine.settings`` (what a command's parser needs) loads
without numba, scipy and the kernels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports

if TYPE_CHECKING:
    from streamid.engine._kernels import warm_up_kernels
    from streamid.engine.coevolution import CoEAState, Coevolution, Progress
    from streamid.engine.ensemble import EnsembleModel
    from streamid.engine.identification import Result, RunSummary, identify
    from streamid.engine.model import MODEL_FORMAT, Model
    from streamid.engine.parallel import EvalHelper
    from streamid.engine.predictor import Predictor
    from streamid.engine.settings import DEFAULT, PAPER, CoEAConfig
    from streamid.engine.validation import (CorrelationReport, RecordReport, ValidationReport, assess, correlation_tests,
                                           r2, validate)

#: Where each exported name lives.
_EXPORTS = {
    "CoEAConfig": "streamid.engine.settings",
    "CoEAState": "streamid.engine.coevolution",
    "Coevolution": "streamid.engine.coevolution",
    "CorrelationReport": "streamid.engine.validation",
    "DEFAULT": "streamid.engine.settings",
    "EnsembleModel": "streamid.engine.ensemble",
    "EvalHelper": "streamid.engine.parallel",
    "MODEL_FORMAT": "streamid.engine.model",
    "Model": "streamid.engine.model",
    "PAPER": "streamid.engine.settings",
    "Predictor": "streamid.engine.predictor",
    "Progress": "streamid.engine.coevolution",
    "RecordReport": "streamid.engine.validation",
    "Result": "streamid.engine.identification",
    "RunSummary": "streamid.engine.identification",
    "ValidationReport": "streamid.engine.validation",
    "assess": "streamid.engine.validation",
    "correlation_tests": "streamid.engine.validation",
    "identify": "streamid.engine.identification",
    "r2": "streamid.engine.validation",
    "validate": "streamid.engine.validation",
    "warm_up_kernels": "streamid.engine._kernels",
}

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
    "Predictor",
    "Progress",
    "RecordReport",
    "Result",
    "RunSummary",
    "ValidationReport",
    "assess",
    "correlation_tests",
    "identify",
    "r2",
    "validate",
    "warm_up_kernels",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals(), __all__)
