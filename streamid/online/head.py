"""What an :class:`~streamid.online.OnlineIdentifier` keeps per modelled output: the champion and its record.

A stream with several outputs gets one :class:`OutputHead` per output (MIMO as
several MISO models, each governed on its own: champion, challengers, drift,
warm starts).  The head is plain mutable state owned by one identifier; the
rules that change it live in :mod:`streamid.online.acceptance` (who wins) and
:mod:`streamid.online.drift` (when the champion stops fitting the data).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from streamid.engine import CoEAState
from streamid.model import Model
from streamid.errors import StreamidError
from streamid.online.drift import DriftMonitor
from streamid.wire.documents import encode_json

__all__ = ["OutputHead", "Watched", "restored_head"]

#: replaced champions whose watch goes on at once (the newest kept)
RETIRED_KEPT = 2


@dataclass(eq=False)
class Watched:
    """A replaced champion still watched for drift: its version, model, monitor and the blocks left to it."""

    version: int
    model: Model
    monitor: DriftMonitor
    blocks_left: int


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
    escalated_runs: int = 0  # escalated runs since the last drift
    drifts: int = 0
    #: replaced champions watched on for one window (a change of model does not erase the evidence of a change)
    retired: deque[Watched] = field(default_factory=lambda: deque(maxlen=RETIRED_KEPT))

    def new_champion(self, model: Model, monitor: DriftMonitor | None, *, window_samples: int = 0) -> None:
        """Serve ``model`` from now on, watched by ``monitor`` (None: not watched); call it before ``version``
        takes the new champion's number (the replaced champion's watch keeps the old one).

        The outgoing champion's monitor, if any and not spent, goes on watching for ``window_samples`` more
        samples (one window: until the new champion's reference holds none of the data the old one was judged
        on).  A new champion is chosen on held-out data that may already hold part of a change, and its
        reference is its own window: without this, a change followed at once by a better challenger went
        unsignalled (2 of 32 simulated dampers) or late (4 more).
        """
        old = self.monitor
        if old is not None and monitor is not None:
            monitor.inherit(old)
        if self.model is not None and old is not None and not old.spent and window_samples > 0:
            blocks = -(-window_samples // old.block_samples)
            old.retire(1 + RETIRED_KEPT)
            self.retired.append(Watched(self.version, self.model, old, blocks))
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


def restored_head(part: dict[str, Any], name: str | None, warnings: list[str]) -> OutputHead | None:
    """The head an :meth:`OutputHead.snapshot` part resumes (None: it holds nothing to resume).

    ``name`` is the output's (None for the stream's first, whose output the part's model or signature names).
    An unreadable model document leaves the head without a champion, unusable populations without a warm
    start; each adds a line to ``warnings``.
    """
    msg, co = part.get("model_message"), part.get("coea_state")
    model = None
    if isinstance(msg, dict):
        try:
            encode_json(msg)
            model = Model.from_dict(msg.get("model"))
        except (ValueError, StreamidError) as exc:
            warnings.append(f"saved model unusable ({exc}); no current model until the next update")
            msg = None
    else:
        msg = None
    output = name or (str(msg.get("output") or (model.output_name if model else "")) if msg else "")
    if not output:
        if co is None:
            return None
        output = str((part.get("signature") or {}).get("output") or "y")
    head = OutputHead(output)
    fails = part.get("failures_in_row", 0)
    head.failures_in_row = fails if isinstance(fails, int) and fails >= 0 else 0
    v = part.get("version", 0)
    if model is not None and msg is not None:
        head.version = int(msg.get("version", v) if isinstance(msg.get("version", v), int) else 0)
        head.document, head.payload = dict(msg), encode_json(msg)
        head.new_champion(model, None)  # no drift watch until the next champion is referenced on its held-out data
    if isinstance(co, str):
        try:
            head.coea_state = CoEAState.from_json(co)
            head.signature = dict(part.get("signature") or {})
        except (StreamidError, ValueError) as exc:
            warnings.append(f"saved populations unusable ({exc}); the next run starts cold")
    return head
