"""Whether an update's candidate becomes the current model, and the :class:`Update` that says so.

The rule (:func:`judge`): the candidate's predictions and figures on the held-out newest
part of its window are finite, its one-step-ahead R^2 there reaches ``min_r2_osa`` and its
free-run R^2 reaches ``min_r2_fr`` (:class:`~streamid.online.StreamConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from streamid.engine import Model
from streamid.online.stream_config import StreamConfig
from streamid.online.update import Outcome
from streamid.online.window_types import Event, Window

__all__ = ["Update", "judge"]


@dataclass(frozen=True, eq=False)
class Update:
    """The result of one update: a new model version, or a refusal with its reason.

    Attributes
    ----------
    kind
        ``"accepted"``, ``"rejected"``, ``"failed"`` or ``"dropped"``.
    reason, code
        Why it was not accepted (empty when it was), in words and as a short key.
    version
        The version served after this update: the new one when accepted, else the previous.
    window
        The window identified.
    outcome
        The run's details: the candidate model, its validation figures, the fitness history...
    document, payload
        The model update document (``streamid.model-update/1``) and its JSON bytes, when accepted.
    event
        The ``update.<kind>`` event.
    """

    kind: str
    reason: str
    code: str
    version: int
    window: Window
    outcome: Outcome
    document: dict[str, Any] | None
    payload: bytes | None
    event: Event

    @property
    def accepted(self) -> bool:
        """Whether this update changed the current model."""
        return self.kind == "accepted"

    @property
    def model(self) -> Model | None:
        """The model of this update (the candidate, also when it was rejected)."""
        return self.outcome.model

    @property
    def metrics(self) -> dict[str, float]:
        """The candidate's validation figures on the window (empty if it was never validated)."""
        return dict(self.outcome.summary.metrics) if self.outcome.summary is not None else {}


def judge(outcome: Outcome, cfg: StreamConfig) -> list[str]:
    """Why a candidate is not accepted (empty: it is)."""
    s = outcome.summary
    if s is None or outcome.model is None:
        return ["no model was produced"]
    m = s.metrics
    reasons = []
    if not s.finite:
        reasons.append("non-finite predictions or metrics")
    if not m.get("r2_osa_val", -np.inf) >= cfg.min_r2_osa:
        reasons.append(f"validation R² OSA {m.get('r2_osa_val', float('nan')):.4g} < min_r2_osa {cfg.min_r2_osa:g}")
    if not m.get("r2_fr_val", -np.inf) >= cfg.min_r2_fr:
        reasons.append(f"validation R² FR {m.get('r2_fr_val', float('nan')):.4g} < min_r2_fr {cfg.min_r2_fr:g}")
    return reasons
