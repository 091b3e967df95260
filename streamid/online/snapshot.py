"""What is kept of one stream between runs: :class:`StreamState` (JSON, never pickled).

:meth:`OnlineIdentifier.state <streamid.online.OnlineIdentifier.state>` returns
one and :meth:`~streamid.online.OnlineIdentifier.from_state` resumes from it:
the version of the last accepted model, that model's update document, the
engine's final populations (the next run starts warm from them) and what they
were fitted to.  The daemon writes it to ``--state-dir``
(:mod:`streamid.daemon.state_store`); the document is::

    {"format": "streamid.daemon-state/1", "stream": ..., "version": 7,
     "signature": {...}, "model_message": {...}, "coea_state": "...",
     "saved_unix_ns": ..., "failures_in_row": 0,
     "others": {"<output>": {"version": 5, "signature": {...}, "model_message": {...},
                             "coea_state": "...", "failures_in_row": 0}, ...},
     "refresh": {"<output>": {"every": 8, "due_in": 3, ..., "normal": {...}}, ...}}

The top-level model fields belong to the stream's first modelled output; ``others``
holds the same per further output of a stream with several (absent in older files); ``refresh`` the refresh
policy's state per output (:meth:`streamid.online.refresh.RefreshTrack.snapshot`; absent in older files).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from streamid.errors import ModelFormatError
from streamid.wire.documents import MAX_VERSION
from streamid.wire.keys import STREAM_NAME_RULE, is_valid_stream_name

__all__ = ["MAX_VERSION", "STATE_FORMAT", "StreamState"]

STATE_FORMAT = "streamid.daemon-state/1"


@dataclass(frozen=True)
class StreamState:
    """What is saved of one stream.

    Attributes
    ----------
    stream
        Stream name.
    version
        Version of the last published model (the next one is ``version + 1``).
    signature
        Facts the warm start depends on (signal names, period, lag bounds).
    model_message
        The last published model message (a JSON object), or None.
    coea_state
        The engine's final populations as its own JSON text, or None.
    saved_unix_ns
        When it was taken (the caller's clock; 0: not given).
    failures_in_row
        Updates that failed since the last accepted one (the next run starts
        cold when it reaches ``cold_after_failures``).
    others
        The same per further modelled output (name -> {"version", "signature", "model_message",
        "coea_state", "failures_in_row"}).
    refresh
        Per modelled output, the refresh policy's state (checked by its reader,
        :meth:`~streamid.online.refresh.RefreshTrack.restore`).
    """

    stream: str
    version: int
    signature: dict[str, Any] = field(default_factory=dict)
    model_message: dict[str, Any] | None = None
    coea_state: str | None = None
    saved_unix_ns: int = 0
    failures_in_row: int = 0
    others: dict[str, dict[str, Any]] = field(default_factory=dict)
    refresh: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_json(self) -> str:
        """The document written to disk (never NaN: ``allow_nan=False``)."""
        return json.dumps(
            {
                "format": STATE_FORMAT,
                "stream": self.stream,
                "version": self.version,
                "signature": self.signature,
                "model_message": self.model_message,
                "coea_state": self.coea_state,
                "saved_unix_ns": int(self.saved_unix_ns),
                "failures_in_row": int(self.failures_in_row),
                **({"others": self.others} if self.others else {}),
                **({"refresh": self.refresh} if self.refresh else {}),
            },
            allow_nan=False,
            separators=(",", ":"),
        )

    @classmethod
    def from_json(cls, text: str, *, source: str = "<state>") -> StreamState:
        """Parse a state document.

        Raises
        ------
        ModelFormatError
            If ``text`` is not a ``streamid.daemon-state/1`` document.
        """
        try:
            doc = json.loads(text)
        except (json.JSONDecodeError, RecursionError, TypeError) as exc:
            raise ModelFormatError(f"{source}: a stream state must be JSON; {exc}") from exc
        if not isinstance(doc, dict) or doc.get("format") != STATE_FORMAT:
            got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
            raise ModelFormatError(f"{source}: expected a document with format {STATE_FORMAT!r}; got {got!r}")
        stream, version = doc.get("stream"), doc.get("version")
        if not is_valid_stream_name(stream):
            raise ModelFormatError(f"{source}: 'stream' must be a stream name ({STREAM_NAME_RULE}); got {stream!r}")
        _check_version(version, "'version'", source)
        assert isinstance(version, int)
        sig, msg, co = doc.get("signature", {}), doc.get("model_message"), doc.get("coea_state")
        if not isinstance(sig, dict) or not (msg is None or isinstance(msg, dict)) or not (co is None or isinstance(co, str)):
            raise ModelFormatError(
                f"{source}: 'signature' must be an object, 'model_message' an object or null and "
                "'coea_state' a string or null"
            )
        saved = doc.get("saved_unix_ns", 0)
        fails = doc.get("failures_in_row", 0)
        others = doc.get("others", {})
        if not isinstance(others, dict) or not all(isinstance(v, dict) for v in others.values()):
            raise ModelFormatError(f"{source}: 'others' must be an object of per-output objects; got {others!r:.200}")
        refresh = doc.get("refresh", {})
        if not isinstance(refresh, dict) or not all(isinstance(v, dict) for v in refresh.values()):
            raise ModelFormatError(f"{source}: 'refresh' must be an object of per-output objects; got {refresh!r:.200}")
        for where, part in [("", doc), *((f"others[{k!r:.80}].", v) for k, v in others.items())]:
            if where:
                _check_version(part.get("version", 0), f"'{where}version'", source)
            m = part.get("model_message")
            if isinstance(m, dict) and "version" in m:
                _check_version(m["version"], f"'{where}model_message.version'", source)
        return cls(
            str(stream), version, sig, msg, co,
            saved if isinstance(saved, int) and not isinstance(saved, bool) else 0,
            fails if isinstance(fails, int) and not isinstance(fails, bool) and fails >= 0 else 0,
            {str(k): dict(v) for k, v in others.items()},
            {str(k): dict(v) for k, v in refresh.items()},
        )


def _check_version(v: Any, what: str, source: str) -> None:
    """A version read from a state: an integer in [0, MAX_VERSION) (the next one must still fit), else refused."""
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < MAX_VERSION:
        raise ModelFormatError(f"{source}: {what} must be an integer in [0, 2**53) (below {MAX_VERSION}, so the next "
                               f"version still fits); got {v!r:.40}")
