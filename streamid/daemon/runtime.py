"""Per-stream runtime state of the daemon: buffer, current model, counters, status.

A :class:`StreamRuntime` is created when a stream is configured or
discovered.  The receiving path only touches its :attr:`~StreamRuntime.buffer`;
a worker applies each identification :class:`~streamid.online.update.Outcome`
with :meth:`StreamRuntime.apply`, which decides what is published: an accepted
model gets the next version (saved to the state directory *before* it is
published, so versions never repeat after a crash), anything else marks the
stream degraded and leaves the previous model current.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from streamid.daemon.config import StreamConfig
from streamid.wire.documents import STATUS_FORMAT, encode_json, model_update_message
from streamid.daemon.state_store import StateStore, StreamState
from streamid.online.window import Window, WindowBuffer
from streamid.online.update import Outcome
from streamid.engine import CoEAState
from streamid.errors import ModelFormatError, StreamidError

__all__ = ["StreamRuntime", "Published"]

_log = logging.getLogger(__name__)


class Published:
    """A model update that was accepted: its version and payload."""

    def __init__(self, version: int, payload: bytes, doc: dict[str, Any]) -> None:
        self.version = version
        self.payload = payload
        self.doc = doc


class StreamRuntime:
    """Everything the daemon keeps about one stream."""

    def __init__(self, name: str, cfg: StreamConfig, notify: Callable[[], None] | None = None) -> None:
        self.name = name
        self.cfg = cfg
        self.buffer = WindowBuffer(name, cfg.window_params(), notify=notify)
        self.lock = threading.Lock()
        self.version = 0
        self.model_payload: bytes | None = None
        self.coea_state: CoEAState | None = None
        self.signature: dict[str, Any] | None = None
        self.degraded = False
        self.degraded_reason = ""
        self.failures_in_row = 0
        self.outcomes: Counter[str] = Counter()
        self.drop_reasons: Counter[str] = Counter()
        self.last: dict[str, Any] = {}
        #: (version, window closed -> published seconds) of recent updates (bounded)
        self.recent_latencies: deque[tuple[int, float]] = deque(maxlen=4096)
        self.busy = False
        self.declared = False
        self.created_unix_ns = time.time_ns()

    # --------------------------------------------------------------- persistence
    def restore(self, st: StreamState) -> None:
        """Resume from a saved state: version, current model, warm-start populations."""
        self.version = st.version
        if st.model_message is not None:
            try:
                self.model_payload = encode_json(st.model_message)
            except ValueError:
                self.model_payload = None
        if st.coea_state is not None:
            try:
                self.coea_state = CoEAState.from_json(st.coea_state)
                self.signature = dict(st.signature)
            except (StreamidError, ValueError) as exc:
                _log.warning("stream %s: saved populations unusable (%s); the next run starts cold", self.name, exc)
                self.coea_state = None

    def snapshot(self) -> StreamState:
        """What is saved of this stream now."""
        msg = json.loads(self.model_payload) if self.model_payload is not None else None
        return StreamState(
            stream=self.name,
            version=self.version,
            signature=dict(self.signature or {}),
            model_message=msg,
            coea_state=self.coea_state.to_json() if self.coea_state is not None else None,
            saved_unix_ns=time.time_ns(),
        )

    # ---------------------------------------------------------------- outcomes
    def apply(self, window: Window, out: Outcome, store: StateStore | None) -> Published | None:
        """Record an outcome; returns what to publish (None: keep the previous model)."""
        with self.lock:
            self.outcomes[out.kind] += 1
            self.last["identification_s"] = out.seconds
            self.last["outcome"] = out.kind
            self.last["unix_ns"] = time.time_ns()
            if out.kind == "dropped":
                self.drop_reasons[out.code or "other"] += 1
                self._degrade(out.reason)
                return None
            if not out.accepted:
                self.failures_in_row += 1
                self._degrade(out.reason)
                return None
            assert out.model is not None and out.summary is not None
            version = self.version + 1
            doc = model_update_message(
                stream=self.name,
                version=version,
                model=out.model.to_dict(),
                window=out.window_meta,
                metrics={k: float(v) for k, v in out.summary.metrics.items()},
                warm=out.warm,
                generations=out.generations,
                identification_s=out.seconds,
                window_closed_unix_ns=window.closed_unix_ns,
                published_unix_ns=time.time_ns(),
            )
            try:
                payload = encode_json(doc)
            except ValueError as exc:  # NaN or infinity somewhere: never published
                self.failures_in_row += 1
                self._degrade(f"model document not finite ({exc})")
                return None
            prev = (self.version, self.model_payload, self.coea_state, self.signature)
            self.version, self.model_payload = version, payload
            self.coea_state, self.signature = out.state, out.signature
            if store is not None:
                try:
                    store.save(self.snapshot())  # before publishing: a crash never reuses a version
                except (OSError, ValueError, ModelFormatError) as exc:
                    self.version, self.model_payload, self.coea_state, self.signature = prev
                    self._degrade(f"state could not be saved ({exc}); model not published")
                    return None
            self.failures_in_row = 0
            self.degraded, self.degraded_reason = False, ""
            self.last["r2_osa_val"] = out.summary.metrics.get("r2_osa_val")
            self.last["r2_fr_val"] = out.summary.metrics.get("r2_fr_val")
            self.last["model_unix_ns"] = doc["published_unix_ns"]
            return Published(version, payload, doc)

    def _degrade(self, reason: str) -> None:
        self.degraded = True
        self.degraded_reason = reason[:500]

    @property
    def force_cold(self) -> bool:
        """Whether the next run starts cold after repeated failures."""
        return self.failures_in_row >= self.cfg.cold_after_failures

    # ------------------------------------------------------------------ status
    def status(self, daemon: dict[str, Any] | None = None) -> dict[str, Any]:
        """The ``streamid.status/1`` document of this stream."""
        c = self.buffer.counters()
        with self.lock:
            doc: dict[str, Any] = {
                "format": STATUS_FORMAT,
                "stream": self.name,
                "unix_ns": time.time_ns(),
                "degraded": self.degraded,
                "degraded_reason": self.degraded_reason,
                "version": self.version,
                "busy": self.busy,
                "samples_in": c.get("samples_in", 0),
                "batches_in": c.get("batches_in", 0),
                "bad": c["bad"],
                "bad_total": c["bad_total"],
                "last_bad": c.get("last_bad") or None,
                "windows": {
                    "closed": c.get("windows_closed", 0),
                    "emitted": c.get("windows_emitted", 0),
                    "coalesced": c.get("windows_coalesced", 0),
                    "dropped": int(self.outcomes.get("dropped", 0)),
                    "pending": c["pending"],
                    "pending_windows": c["pending_windows"],
                    "max_pending_windows": c["max_pending_windows"],
                    "pending_bytes": c["pending_bytes"],
                    "pending_windows_peak": c["pending_windows_peak"],
                    "pending_bytes_peak": c["pending_bytes_peak"],
                    "pending_bytes_max": c["pending_bytes_max"],
                },
                "identifications": {k: int(self.outcomes.get(k, 0)) for k in ("accepted", "rejected", "failed", "dropped")},
                "drop_reasons": dict(self.drop_reasons),
                "last": {k: v for k, v in self.last.items() if v is not None},
                "gaps": c.get("gaps", 0),
                "gap_samples": c.get("gap_samples", 0),
                "resets": c["resets"],
                "unaligned": c.get("unaligned", 0),
                "samples_discarded": c.get("samples_discarded", 0),
                "period_ns": c["period_ns"],
                "window_samples": c["window_samples"],
                "hop_samples": c["hop_samples"],
                "inputs": c["inputs"],
                "outputs": c["outputs"],
            }
        if daemon is not None:
            doc["daemon"] = daemon
        return doc
