"""The identification engine: coevolutionary RBF-NARX (see the modules for the method's details).

``identify`` (one identification, possibly several runs), ``Coevolution`` (one
steppable run with exportable ``CoEAState`` for warm starts), ``Model`` (prediction,
free run, ``streamid.model/1`` JSON; ``EnsembleModel``: the mean of several networks, ``/3``: these live in
:mod:`streamid.model` and are named here too), ``validate`` / ``assess`` (a model on a record it never saw) /
``r2`` / ``correlation_tests``, ``EvalHelper`` (a helper process evaluating half of every population batch: the
second core), ``warm_up_kernels`` (compile or load the compiled free-run loops before time-bound work).

Grouped by what it does (docs/architecture.md): :mod:`~streamid.engine.fit` (the network's least-squares fit, the
lag matrix), :mod:`~streamid.engine.search` (one coevolution run, runs in processes),
:mod:`~streamid.engine.choice` (the choice among candidates and what is made of the kept one), and at the top
:mod:`~streamid.engine.identification` (``identify``), :mod:`~streamid.engine.settings`,
:mod:`~streamid.engine.validation`, :mod:`~streamid.engine.restarts` and :mod:`~streamid.engine.warmup`.

May import: the stdlib, numpy, scipy, threadpoolctl, numba, ``streamid.errors``, ``streamid._lazy``,
``streamid.threads``, ``streamid.model`` and ``streamid.engine.*``; never the online core, the daemon, the wire,
the logs, the viewer or the transport (tests/test_layout.py).

Every name is imported on first use: ``streamid.engine.settings`` (what a command's parser needs) loads
without numba, scipy and the kernels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports

if TYPE_CHECKING:
    from streamid.engine.warmup import warm_up_kernels
    from streamid.engine.search.coevolution import CoEAState, Coevolution, Progress
    from streamid.model.ensemble import EnsembleModel
    from streamid.engine.identification import Result, RunSummary, identify
    from streamid.model.narx import MODEL_FORMAT, Model
    from streamid.engine.search.parallel import EvalHelper
    from streamid.model.predictor import Predictor
    from streamid.engine.settings import DEFAULT, PAPER, CoEAConfig
    from streamid.engine.validation import (CorrelationReport, RecordReport, ValidationReport, assess, correlation_tests,
                                           r2, validate)

#: Where each exported name lives.
_EXPORTS = {
    "CoEAConfig": "streamid.engine.settings",
    "CoEAState": "streamid.engine.search.coevolution",
    "Coevolution": "streamid.engine.search.coevolution",
    "CorrelationReport": "streamid.engine.validation",
    "DEFAULT": "streamid.engine.settings",
    "EnsembleModel": "streamid.model.ensemble",
    "EvalHelper": "streamid.engine.search.parallel",
    "MODEL_FORMAT": "streamid.model.narx",
    "Model": "streamid.model.narx",
    "PAPER": "streamid.engine.settings",
    "Predictor": "streamid.model.predictor",
    "Progress": "streamid.engine.search.coevolution",
    "RecordReport": "streamid.engine.validation",
    "Result": "streamid.engine.identification",
    "RunSummary": "streamid.engine.identification",
    "ValidationReport": "streamid.engine.validation",
    "assess": "streamid.engine.validation",
    "correlation_tests": "streamid.engine.validation",
    "identify": "streamid.engine.identification",
    "r2": "streamid.engine.validation",
    "validate": "streamid.engine.validation",
    "warm_up_kernels": "streamid.engine.warmup",
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
