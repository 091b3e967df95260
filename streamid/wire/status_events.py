"""What a stream's status says has changed, as events: :class:`StatusChanges` (pure, no I/O).

The daemon publishes each stream's ``streamid.status/1`` document every ``status_every_s``
(docs/daemon.md).  A consumer of the models (a controller, ``streamid watch``) wants to be told when it
changes in a way that bears on trusting them:

* ``degraded``: the served model fails the floors on current data, no model yet, or updates fail
  (said at once if the stream is degraded at the first status seen);
* ``healthy``: no longer degraded;
* ``drift``: an output's drift count rose, i.e. its served model no longer fits the incoming data (the
  next identification starts from the change, estimated at ``drift_t_ns``).  The drifts counted before
  the first status seen are history, not events.

The statuses come from the network: every value used is checked here, what is remembered is bounded
(:data:`MAX_REMEMBERED` streams and outputs, :data:`MAX_OUTPUTS_LOOKED_AT` outputs of one status), and
:meth:`StatusEvent.text` escapes the names and reasons (:func:`~streamid.wire.names.printable`).
"""

from __future__ import annotations

import datetime
from dataclasses import asdict, dataclass
from typing import Any

from streamid.wire.names import printable

__all__ = ["MAX_OUTPUTS_LOOKED_AT", "MAX_REMEMBERED", "STATUS_EVENT_FORMAT", "StatusChanges", "StatusEvent"]

#: The format of an event as a JSON document (``streamid watch --json`` prints them beside the model updates).
STATUS_EVENT_FORMAT = "streamid.status-event/1"
#: Streams and outputs whose last status is remembered.
MAX_REMEMBERED = 10_000
#: Outputs of one status looked at (a daemon models at most a few; a forged status may list more).
MAX_OUTPUTS_LOOKED_AT = 64


@dataclass(frozen=True)
class StatusEvent:
    """One change a stream's status shows (see the module docstring for the kinds).

    ``output``, ``drifts``, ``new`` and ``drift_t_ns`` are set for a ``drift`` (``new``: drifts since the
    last status seen, usually 1); ``reason`` for ``degraded``; ``version`` is the served model's, or None.
    """

    kind: str
    stream: str
    version: int | None = None
    output: str = ""
    drifts: int = 0
    new: int = 0
    drift_t_ns: int | None = None
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The event as a JSON-able document (``"format": "streamid.status-event/1"``)."""
        return {"format": STATUS_EVENT_FORMAT, **asdict(self)}

    def text(self) -> str:
        """One line for a reader, escaped (names and reasons came from the network)."""
        v = f"v{self.version}" if self.version is not None else ""
        if self.kind == "degraded":
            line = f"{self.stream} DEGRADED: {self.reason}"
        elif self.kind == "healthy":
            line = f"{self.stream} healthy again" + (f" (model {v})" if v else "")
        else:
            served = f"the served model {v}" if v else "the served model"
            t = self.drift_t_ns
            when = "change time not given" if t is None else f"change estimated at stream time {_stream_time(t)}"
            more = f"{self.new} new, " if self.new > 1 else ""
            line = (f"{self.stream} DRIFT on {self.output}: {served} no longer fits the incoming data ({when}; "
                    f"{more}{self.drifts} so far); the next identification starts from the change")
        return printable(line, 2000)


class StatusChanges:
    """The events each new status of a stream brings, remembering the last one seen (bounded).

    Single-threaded: a caller fed from several threads holds its own lock.
    """

    def __init__(self) -> None:
        self._seen: dict[tuple[str, str], Any] = {}

    def __len__(self) -> int:
        """Streams and outputs remembered (at most :data:`MAX_REMEMBERED`)."""
        return len(self._seen)

    def update(self, status: dict[str, Any]) -> list[StatusEvent]:
        """The events ``status`` (a parsed ``streamid.status/1`` document) brings since its stream's last one."""
        name = str(status.get("stream", ""))
        out: list[StatusEvent] = []
        bad = bool(status.get("degraded"))
        kept, was_bad = self._remember((name, ""), bad)
        if kept and bad != bool(was_bad):  # a stream degraded at its first status is said at once
            out.append(StatusEvent("degraded" if bad else "healthy", name, _count(status.get("version")),
                                   reason=str(status.get("degraded_reason", "")) if bad else ""))
        models = status.get("models")
        for output, m in list(models.items())[:MAX_OUTPUTS_LOOKED_AT] if isinstance(models, dict) else ():
            n = _count(m.get("drifts")) if isinstance(m, dict) else None
            if n is None:
                continue
            kept, before = self._remember((name, str(output)), n)
            if kept and before is not None and n > before:  # (at first sight, the drifts before are history)
                out.append(StatusEvent("drift", name, _count(m.get("version")), str(output), n, n - before,
                                       _count(m.get("drift_t_ns"))))
        return out

    def _remember(self, key: tuple[str, str], now: Any) -> tuple[bool, Any]:
        """(whether ``key`` is remembered now, what it was before: None at first sight)."""
        if key not in self._seen and len(self._seen) >= MAX_REMEMBERED:
            return False, None
        before, self._seen[key] = self._seen.get(key), now
        return True, before


def _count(v: Any) -> int | None:
    """``v`` if it is a count or a time as the daemon writes them (an integer in [0, 2**63)), else None."""
    return v if isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**63 else None


def _stream_time(t_ns: int) -> str:
    """A stream's time for a reader: UTC if it looks like a wall clock (after 1973), else seconds from its start."""
    if t_ns > 10**17:
        try:
            when = datetime.datetime.fromtimestamp(t_ns / 1e9, tz=datetime.timezone.utc)
            return when.isoformat(timespec="milliseconds")
        except (OverflowError, OSError, ValueError):
            pass
    return f"{t_ns / 1e9:.3f} s"
