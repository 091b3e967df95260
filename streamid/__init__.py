"""streamid: streaming online nonlinear system identification.

A NARX model y(t) = F[y(t-1..t-ny), u(t-1..t-nu)] with F a Gaussian RBF
network is identified by a cooperative coevolution of a binary Adaptive Harmony
Search (lag selection) and Differential Evolution (centres and widths), and
re-identified online from samples arriving over Eclipse Zenoh.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from streamid.errors import StreamidError

try:
    __version__ = version("streamid")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+local"

__all__ = [
    "StreamidError",
    "__version__",
    "CoEAConfig",
    "CoEAState",
    "Coevolution",
    "EvalHelper",
    "Model",
    "Result",
    "identify",
    "validate",
]

_ENGINE_EXPORTS = {
    "CoEAConfig": "streamid.engine.settings",
    "CoEAState": "streamid.engine.coevolution",
    "Coevolution": "streamid.engine.coevolution",
    "EvalHelper": "streamid.engine.parallel",
    "Model": "streamid.engine.model",
    "Result": "streamid.engine.identify",
    "identify": "streamid.engine.identify",
    "validate": "streamid.engine.validation",
}


def __getattr__(name: str) -> object:
    """Engine names re-exported lazily (``import streamid`` stays light for the CLI and the daemon)."""
    module = _ENGINE_EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'streamid' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
