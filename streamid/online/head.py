"""What an :class:`~streamid.online.OnlineIdentifier` keeps per modelled output: the champion and its record.

A stream with several outputs gets one :class:`OutputHead` per output (MIMO as
several MISO models, each governed on its own: champion, challengers, drift,
warm starts).  The head is plain mutable state owned by one identifier; the
rules that change it live in :mod:`streamid.online.acceptance` (who wins) and
:mod:`streamid.online.drift` (when the champion stops fitting the data).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from streamid.engine import CoEAState, Model
from streamid.online.drift import DriftSettings, ResidualMonitor

__all__ = ["OutputHead"]


@dataclass(eq=False)
class OutputHead:
    """The served model of one output and what is known about it (mutable, single-threaded)."""

    output: str
    version: int = 0  # version of this output's champion (0: none yet)
    model: Model | None = None
    document: dict[str, Any] | None = None
    payload: bytes | None = None
    coea_state: CoEAState | None = None
    signature: dict[str, Any] | None = None
    failures_in_row: int = 0
    # the champion's record
    since_t_ns: int | None = None  # stream time of the window that made it champion
    since_unix_ns: int = 0
    wins: int = 0  # challengers it beat
    replaced: int = 0  # champions of this output replaced by a challenger (losses)
    current: dict[str, Any] = field(default_factory=dict)  # its last re-validation on current held-out data
    # drift
    monitor: ResidualMonitor | None = None
    drift_t_ns: int | None = None  # estimated start of the last detected change (windows are cut to begin there)
    escalate: bool = False  # the next identification runs with the drift budget
    drifts: int = 0

    def new_champion(self, model: Model, mse_ref: float, settings: DriftSettings | None, period_ns: int) -> None:
        """Start monitoring a new champion (``mse_ref``: its OSA mean-square error on its held-out data)."""
        self.model = model
        self.monitor = ResidualMonitor(settings, period_ns, mse_ref) if settings is not None else None
        self.wins = 0
        self.current = {}

    def residuals(self, u: np.ndarray, y: np.ndarray) -> np.ndarray | None:
        """The champion's one-step-ahead residuals on the newest rows of ``u``/``y`` (the first ``max_lag`` are history)."""
        m = self.model
        if m is None or u.shape[1] != m.n_inputs or y.shape[0] <= m.max_lag:
            return None
        with np.errstate(over="ignore", invalid="ignore"):
            pred = m.predict_osa(u, y)
        return np.asarray(y[m.max_lag :] - pred[m.max_lag :], dtype=np.float64)

    def snapshot(self) -> dict[str, Any]:
        """The part of :class:`~streamid.online.snapshot.StreamState` that belongs to this output."""
        return {
            "version": self.version,
            "signature": dict(self.signature or {}),
            "model_message": self.document,
            "coea_state": self.coea_state.to_json() if self.coea_state is not None else None,
            "failures_in_row": self.failures_in_row,
        }
