"""streamid: streaming online nonlinear system identification.

A NARX model y(t) = F[y(t-1..t-ny), u(t-1..t-nu)] with F a Gaussian RBF
network is identified by a cooperative coevolution of a binary Adaptive Harmony
Search (lag selection) and Differential Evolution (centres and widths), and
re-identified online from samples arriving over Eclipse Zenoh.

The engine half: :func:`identify`, :class:`Coevolution` / :class:`CoEAState`,
:class:`CoEAConfig`, :class:`Model`, :class:`Result`, :func:`validate`, :func:`assess` (a model on a record it
never saw),
:class:`EvalHelper`.  The streaming half: :class:`OnlineIdentifier` (a stream's
online identification as a library), :class:`Daemon` with :class:`DaemonConfig` and
:class:`StreamConfig`, :class:`SampleBatch` (the samples on the wire), and on the
client side :class:`ModelSubscriber` and :func:`latest_model`, and :class:`Predictor` (a received model run
sample by sample in a control loop).

Every name is imported on first use, so ``import streamid`` stays light (no numpy,
Zenoh, Rerun or MCAP) for the command line and the daemon's start.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports
from streamid._version import __version__
from streamid.errors import StreamidError

if TYPE_CHECKING:
    from streamid.daemon.config import DaemonConfig
    from streamid.online.stream_config import StreamConfig
    from streamid.daemon.service import Daemon
    from streamid.engine.search.coevolution import CoEAState, Coevolution
    from streamid.engine.identification import Result, identify
    from streamid.model.narx import Model
    from streamid.engine.search.parallel import EvalHelper
    from streamid.model.predictor import Predictor
    from streamid.engine.settings import CoEAConfig
    from streamid.engine.validation import assess, validate
    from streamid.online.identifier import OnlineIdentifier
    from streamid.transport.client import ModelSubscriber, latest_model
    from streamid.wire.codec import SampleBatch


#: Where each lazily exported name lives.
_EXPORTS = {
    # the engine
    "CoEAConfig": "streamid.engine.settings",
    "CoEAState": "streamid.engine.search.coevolution",
    "Coevolution": "streamid.engine.search.coevolution",
    "EvalHelper": "streamid.engine.search.parallel",
    "Model": "streamid.model.narx",
    "Result": "streamid.engine.identification",
    "identify": "streamid.engine.identification",
    "validate": "streamid.engine.validation",
    "assess": "streamid.engine.validation",
    "Predictor": "streamid.model.predictor",
    # streaming
    "OnlineIdentifier": "streamid.online.identifier",
    "Daemon": "streamid.daemon.service",
    "DaemonConfig": "streamid.daemon.config",
    "StreamConfig": "streamid.online.stream_config",
    "SampleBatch": "streamid.wire.codec",
    "ModelSubscriber": "streamid.transport.client",
    "latest_model": "streamid.transport.client",
}

__all__ = [
    "StreamidError",
    "__version__",
    # the engine
    "CoEAConfig",
    "CoEAState",
    "Coevolution",
    "EvalHelper",
    "Model",
    "Result",
    "identify",
    "validate",
    "assess",
    "Predictor",
    # streaming
    "OnlineIdentifier",
    "Daemon",
    "DaemonConfig",
    "StreamConfig",
    "SampleBatch",
    "ModelSubscriber",
    "latest_model",
]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals(), __all__)
