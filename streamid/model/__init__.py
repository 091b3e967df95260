"""The identified model, as a package of its own: what ``watch``, the FMU and C export, a controller's
:class:`Predictor` and the client library share, without the search that made it.

Owns: the JSON document (``streamid.model/1`` .. ``/5``) and its reading limits (:mod:`~streamid.model.limits`),
the regressors and their normalisation (:mod:`~streamid.model.regressors`), the network and its free-run
simulation (:mod:`~streamid.model.narx`, :mod:`~streamid.model.freerun`, the compiled loops of
:mod:`~streamid.model.kernels`), ensembles of networks (:mod:`~streamid.model.ensemble`), the estimation domain
(:mod:`~streamid.model.domain`) and the sample-by-sample :class:`Predictor` (:mod:`~streamid.model.predictor`; its
free run one instant a call, :meth:`Predictor.step`, in :mod:`~streamid.model.stepping`).

May import: the stdlib, numpy, numba, ``streamid.errors``, ``streamid.bounded_files``, ``streamid.threads`` and
``streamid.model.*``; never the engine, the online core, the daemon or the transport (tests/test_layout.py).

:class:`Model` and :class:`EnsembleModel` are imported here, so that a model document of any format reads as
its class whichever module of the package was imported first (``Model.from_dict`` hands the ensemble formats to
the subclass that reads them); the :class:`Predictor` (numba) is imported on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports
from streamid.model.ensemble import EnsembleModel
from streamid.model.narx import MODEL_FORMAT, MODEL_FORMATS, Model

if TYPE_CHECKING:
    from streamid.model.predictor import Predictor
    from streamid.model.stepping import Step

_EXPORTS = {"Predictor": "streamid.model.predictor", "Step": "streamid.model.stepping"}

__all__ = ["EnsembleModel", "MODEL_FORMAT", "MODEL_FORMATS", "Model", "Predictor", "Step"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals(), __all__)
