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

from streamid.engine import CoEAState, Model
from streamid.online.drift import DriftMonitor

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
    monitor: DriftMonitor | None = None
    drift_t_ns: int | None = None  # estimated start of the last detected change (windows are cut to begin there)
    escalate: bool = False  # the next identification runs with the drift budget
    drifts: int = 0

    def new_champion(self, model: Model, monitor: DriftMonitor | None) -> None:
        """Serve ``model`` from now on, watched by ``monitor`` (None: not watched)."""
        self.model = model
        self.monitor = monitor
        self.wins = 0
        self.current = {}

    def snapshot(self) -> dict[str, Any]:
        """The part of :class:`~streamid.online.snapshot.StreamState` that belongs to this output."""
        return {
            "version": self.version,
            "signature": dict(self.signature or {}),
            "model_message": self.document,
            "coea_state": self.coea_state.to_json() if self.coea_state is not None else None,
            "failures_in_row": self.failures_in_row,
        }
