"""Client side of the daemon: receive identified models over Zenoh.

>>> from streamid.transport.client import ModelSubscriber, latest_model
>>> with ModelSubscriber("tcp/127.0.0.1:7447", "bench1", lambda up: print(up.version, up.model)):  # doctest: +SKIP
...     ...
>>> up = latest_model("tcp/127.0.0.1:7447", "bench1", timeout_s=2.0)                   # doctest: +SKIP
>>> yhat = up.model.simulate(u, y[: up.model.max_lag])                                  # doctest: +SKIP

Where to connect is an endpoint string (``"tcp/127.0.0.1:7447"``), a
:class:`~streamid.transport.zenoh_bus.ZenohSettings` (TLS, access control, ...)
or an open :class:`~streamid.transport.zenoh_bus.Bus`.  :func:`latest_model`
tells the two ways of getting nothing apart: :class:`~streamid.errors.NoDaemonError`
(nothing reachable at the endpoint) and :class:`~streamid.errors.NoModelYetError`
(reachable, but no model of that stream yet); ``default=None`` returns None for both.

Each update is a :class:`~streamid.transport.updates.ModelUpdate`: the engine's
:class:`~streamid.model.Model` rebuilt from the published JSON, its version, the
output it predicts, why it was accepted, the window it was fitted on and its
validation metrics.  A stream with several outputs has one current model per output
(:func:`latest_models`, :meth:`ModelSubscriber.latest_per_output`).

Nothing a remote party publishes makes a client raise: a malformed document, one on
a key of another stream, or one of the wrong kind is skipped, counted and warned
about (at most one warning per reason every ``warn_every_s`` seconds).  A query for the
current models (:func:`latest_model`, ``fetch_latest``) keeps at most
:data:`MODEL_QUERY_MAX_REPLIES` replies of at most :data:`MODEL_QUERY_MAX_BYTES` together
(each at most the wire format's 8 MiB); the replies beyond are counted as ``query_bound``.
"""

from __future__ import annotations

import dataclasses

import logging
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, Union

from streamid.errors import ConfigError, ModelFormatError, NoDaemonError, NoModelYetError, TransportError
from streamid.transport.updates import ModelUpdate, is_newer, parse_model_update, recency
from streamid.transport.replies import Replies
from streamid.transport.zenoh_bus import Bus, ZenohSettings, _Handle
from streamid.wire.documents import MAX_DOCUMENT_BYTES, parse_status
from streamid.wire.keys import PREFIX, check_stream_name, model_key, parse_key, rejected_key, status_key
from streamid.wire.names import printable
from streamid.wire.status_events import StatusChanges, StatusEvent

__all__ = [
    "MODEL_QUERY_MAX_BYTES",
    "MODEL_QUERY_MAX_REPLIES",
    "STATUS_SKIPS",
    "ModelSubscriber",
    "ModelUpdate",
    "NoDaemonError",
    "NoModelYetError",
    "Target",
    "latest_model",
    "latest_models",
    "latest_status",
]

_log = logging.getLogger(__name__)

#: Where to reach the daemon: an endpoint string, settings, or an open session.
Target = Union[str, ZenohSettings, Bus]
#: Why a received document was skipped (the keys of ``ModelSubscriber.skipped``).
SKIP_REASONS = ("malformed", "key_mismatch", "kind_mismatch", "too_many")
#: What a query for the current models keeps at most: replies (one per output of each stream answered) and their
#: bytes together; the replies beyond are measured, not read, and counted as ``query_bound`` (a flood of answers).
MODEL_QUERY_MAX_REPLIES = 1024
MODEL_QUERY_MAX_BYTES = 64 * 1024 * 1024


def _open(bus_or_settings: Target, wait_s: float | None = None) -> tuple[Bus, bool]:
    """The session to use and whether it is ours; ``wait_s`` caps how long a client waits for its endpoint."""
    if isinstance(bus_or_settings, Bus):
        return bus_or_settings, False
    if isinstance(bus_or_settings, str):
        bus_or_settings = ZenohSettings(connect=(bus_or_settings,))  # checks the endpoint's form
    if isinstance(bus_or_settings, ZenohSettings):
        if wait_s is not None:
            own = bus_or_settings.connect_wait_s
            bus_or_settings = dataclasses.replace(bus_or_settings, connect_wait_s=wait_s if own is None else min(own, wait_s))
        return Bus(bus_or_settings), True
    raise ConfigError(
        "where to connect must be an endpoint string such as 'tcp/127.0.0.1:7447', ZenohSettings or an open Bus; "
        f"got {type(bus_or_settings).__name__} {bus_or_settings!r}"
    )


def _where(bus: Bus) -> str:
    s = bus.settings
    return ", ".join(s.connect) or ", ".join(f"listening on {e}" for e in s.listen) or "the --zenoh-config endpoints"


#: The reasons :attr:`ModelSubscriber.skipped` counts for status messages (``on_event``), not model updates.
STATUS_SKIPS = frozenset({"malformed_status", "status_key_mismatch"})


class _Skips:
    """Skipped documents: counted per reason, one warning per reason at most every ``every_s`` seconds."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.counts: dict[str, int] = {r: 0 for r in SKIP_REASONS}
        self._last_warn: dict[str, float] = {}
        self._quiet: dict[str, int] = {}
        self._lock = threading.Lock()

    def skip(self, reason: str, key: str, message: str, n: int = 1) -> None:
        now = time.monotonic()
        with self._lock:
            self.counts[reason] = self.counts.get(reason, 0) + n
            last = self._last_warn.get(reason)
            if last is not None and now - last < self.every_s:
                self._quiet[reason] = self._quiet.get(reason, 0) + 1
                return
            self._last_warn[reason] = now
            quiet = self._quiet.pop(reason, 0)
        more = f" ({quiet} more skipped since the last warning)" if quiet else ""
        what = "status" if reason in STATUS_SKIPS else "model update"
        _log.warning("%s on %s skipped (%s): %s%s", what, printable(key, 200), reason, message, more)

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)

    def total(self) -> int:
        return sum(self.snapshot().values())


def _check(key: str, payload: bytes, skips: _Skips) -> ModelUpdate | None:
    """The update in ``payload`` received on ``key``, or None (skipped, counted, warned) if it is not a valid one."""
    try:
        k_stream, kind = parse_key(key)
    except ConfigError as exc:
        skips.skip("key_mismatch", key, str(exc))
        return None
    if kind not in ("model", "rejected"):
        skips.skip("kind_mismatch", key, f"model updates come on streamid/<stream>/model or /rejected, not {kind!r}")
        return None
    try:
        up = parse_model_update(payload)
    except ModelFormatError as exc:
        skips.skip("malformed", key, str(exc))
        return None
    except Exception as exc:  # noqa: BLE001 - a parser bug must not kill Zenoh's thread nor the caller
        skips.skip("malformed", key, f"{type(exc).__name__}: {printable(exc, 300)}")
        return None
    if up.stream != k_stream:
        skips.skip("key_mismatch", key, f"the document names stream {up.stream!r} but came on the key of {k_stream!r}")
        return None
    if up.accepted != (kind == "model"):
        skips.skip("kind_mismatch", key, f"a document with accepted={str(up.accepted).lower()} on the {kind!r} key "
                   "(accepted models come on /model, rejected challengers on /rejected)")
        return None
    return up


def _pick(models: dict[str, ModelUpdate], output: str | None) -> ModelUpdate | None:
    """The model of ``output``; None: the only one, or the first output in name order."""
    if output is not None:
        return models.get(output)
    return models[min(models)] if models else None


class ModelSubscriber:
    """Hand every new model of a stream to ``callback``.

    Parameters
    ----------
    settings
        An endpoint string such as ``"tcp/127.0.0.1:7447"`` or
        :class:`~streamid.transport.zenoh_bus.ZenohSettings` (a session is opened and
        closed with the subscriber), or an open :class:`~streamid.transport.zenoh_bus.Bus`.
    stream
        Stream name, or ``"*"`` for every stream.
    callback
        ``callback(update: ModelUpdate)``, called on a Zenoh thread, one at a time, with
        each new accepted model in order per (stream, output): an update is delivered if it
        is newer than the last one of its output (:func:`~streamid.transport.updates.is_newer`:
        a higher version, or a later daemon life), older or repeated ones are skipped.  An
        exception it raises is logged, never propagated.
    fetch_latest
        Query the current models at start, so a late subscriber gets them at once.
    latest_timeout_s
        How long that first query waits.
    include_rejected
        Also deliver the rejected challengers (``update.accepted`` False, published on
        ``streamid/<stream>/rejected``), as they come.
    warn_every_s
        At most one warning per skip reason in this many seconds.
    max_models
        Bound on the (stream, output) pairs kept: a model of a new pair beyond it is skipped
        (``too_many``), so publishers inventing names cannot make the subscriber grow without end.
    on_event
        ``on_event(event: StatusEvent)``, called on a Zenoh thread with each change the streams' status
        shows that bears on trusting their models (:mod:`streamid.wire.status_events`): ``drift`` (an
        output's served model no longer fits the incoming data), ``degraded``, ``healthy``.  None: the
        status is not subscribed to.  An exception it raises is logged, never propagated; a status that is
        not a valid document is skipped (``malformed_status``).

    Attributes
    ----------
    latest : dict
        Newest accepted update per stream (of any output; see :meth:`latest_per_output`).
    skipped : dict
        Documents skipped per reason: ``malformed`` (not a valid model update),
        ``key_mismatch`` (naming another stream than its key), ``kind_mismatch``
        (an accepted model on the rejected key or the other way round), ``too_many`` (beyond
        ``max_models``); with ``on_event``, ``malformed_status`` (not a valid status document) and
        ``status_key_mismatch`` (a status naming another stream than its key) (:data:`STATUS_SKIPS`).
    stale : int
        Valid updates not newer than the current one of their output (e.g. a query reply
        that repeats a version already received).
    rejected : int
        Rejected challengers delivered.
    """

    def __init__(
        self,
        settings: Target,
        stream: str,
        callback: Callable[[ModelUpdate], object],
        *,
        fetch_latest: bool = True,
        latest_timeout_s: float = 1.0,
        include_rejected: bool = False,
        warn_every_s: float = 10.0,
        max_models: int = 4096,
        on_event: Callable[[StatusEvent], object] | None = None,
    ) -> None:
        if stream != "*":
            check_stream_name(stream)
        if isinstance(max_models, bool) or not isinstance(max_models, int) or max_models < 1:
            raise ConfigError(f"max_models must be an integer >= 1; got {max_models!r}")
        self.max_models = max_models
        self.stream = stream
        self.callback = callback
        self.include_rejected = include_rejected
        self.latest: dict[str, ModelUpdate] = {}
        self.stale = 0
        self.rejected = 0
        self._models: dict[tuple[str, str], ModelUpdate] = {}
        self._skips = _Skips(warn_every_s)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._order = threading.RLock()
        self._subs: list[_Handle] = []
        self.on_event = on_event
        self._changes = StatusChanges()
        self._bus, self._owned = _open(settings)
        key = f"{PREFIX}/*/model" if stream == "*" else model_key(stream)
        try:
            if on_event is not None:  # first: a status saying "degraded" comes before the models are fetched
                skey = f"{PREFIX}/*/status" if stream == "*" else status_key(stream)
                self._subs.append(self._bus.subscribe(skey, self._on_status))
            self._subs.append(self._bus.subscribe(key, self._on_payload))
            if include_rejected:
                rkey = f"{PREFIX}/*/rejected" if stream == "*" else rejected_key(stream)
                self._subs.append(self._bus.subscribe(rkey, self._on_payload))
            if fetch_latest:
                replies = _bounded_get(self._bus, key, latest_timeout_s, self._skips)
                for _k, payload in replies:
                    self._on_payload(_k, payload)
        except BaseException:
            self.close()
            raise

    @property
    def skipped(self) -> dict[str, int]:
        return self._skips.snapshot()

    @property
    def errors(self) -> int:
        """Payloads skipped for any reason (the sum of :attr:`skipped`)."""
        return self._skips.total()

    def _deliver(self, up: ModelUpdate) -> None:
        try:
            self.callback(up)
        except Exception:  # noqa: BLE001 - the user's callback must not kill zenoh's thread
            _log.exception("ModelSubscriber callback failed on version %d of %s (output %s)", up.version,
                           up.stream, printable(up.output, 80))

    def _on_payload(self, key: str, payload: bytes) -> None:
        up = _check(key, payload, self._skips)
        if up is None:
            return
        with self._order:  # one delivery at a time, in order per (stream, output)
            if not up.accepted:
                if self.include_rejected:
                    with self._lock:
                        self.rejected += 1
                    self._deliver(up)
                return
            with self._cond:
                prev = self._models.get((up.stream, up.output))
                full = prev is None and len(self._models) >= self.max_models
                if not full and not is_newer(up, prev):
                    self.stale += 1
                    return
                if not full:
                    self._models[(up.stream, up.output)] = up
                    if is_newer(up, self.latest.get(up.stream)):
                        self.latest[up.stream] = up
                    self._cond.notify_all()
            if full:
                self._skips.skip("too_many", key, f"already {self.max_models} (stream, output) pairs kept (max_models)")
                return
            self._deliver(up)

    def _on_status(self, key: str, payload: bytes) -> None:
        try:
            st = parse_status(payload)
        except ModelFormatError as exc:
            self._skips.skip("malformed_status", key, str(exc))
            return
        try:
            stream, _ = parse_key(key)
        except ConfigError as exc:
            self._skips.skip("malformed_status", key, str(exc))
            return
        if st.get("stream", stream) != stream:
            self._skips.skip("status_key_mismatch", key, f"a status naming stream {printable(str(st['stream']), 80)}")
            return
        with self._order:  # one delivery at a time (events and models), in the order the statuses came
            for ev in self._changes.update({**st, "stream": stream}):
                try:
                    self.on_event(ev)  # type: ignore[misc]  # set: the status is subscribed only then
                except Exception:  # noqa: BLE001 - the user's callback must not kill zenoh's thread
                    _log.exception("ModelSubscriber on_event failed on %s", ev.text())

    def latest_per_output(self, stream: str | None = None) -> dict[str, ModelUpdate]:
        """The newest accepted model of each output of ``stream`` (default: the subscribed one), by output name."""
        name = stream or self.stream
        with self._lock:
            return {out: up for (s, out), up in sorted(self._models.items()) if s == name}

    def current(self, stream: str | None = None, output: str | None = None) -> ModelUpdate | None:
        """The newest accepted model of ``output`` (None: the only output, or the first in name order)."""
        return _pick(self.latest_per_output(stream), output)

    def wait_for_version(
        self, version: int, timeout_s: float, stream: str | None = None, output: str | None = None
    ) -> ModelUpdate | None:
        """Block until a model of at least ``version`` arrived (of ``output`` if given; None on timeout)."""
        name = stream or self.stream
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                up = self.latest.get(name) if output is None else self._models.get((name, output))
                if up is not None and up.version >= version:
                    return up
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def close(self) -> None:
        """Undeclare the subscriptions (and close the session if it was opened here)."""
        while self._subs:
            self._subs.pop().close()
        if self._owned:
            self._bus.close()

    def __enter__(self) -> ModelSubscriber:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _bounded_get(bus: Bus, key: str, timeout_s: float, skips: _Skips | None = None) -> Replies:
    """A query for model updates on ``key``, within :data:`MODEL_QUERY_MAX_REPLIES` / :data:`MODEL_QUERY_MAX_BYTES`
    (what is dropped is counted in ``skips`` as ``query_bound``)."""
    got = bus.get(key, timeout_s=timeout_s, all_replies=True, max_replies=MODEL_QUERY_MAX_REPLIES,
                  max_bytes=MODEL_QUERY_MAX_BYTES, max_reply_bytes=MAX_DOCUMENT_BYTES)
    if got.dropped and skips is not None:
        skips.skip("query_bound", key, f"{got.dropped} replies ({got.dropped_bytes} bytes) dropped unread beyond what "
                   f"one query keeps ({MODEL_QUERY_MAX_REPLIES} replies, {MODEL_QUERY_MAX_BYTES} bytes together, "
                   f"{MAX_DOCUMENT_BYTES} each)", got.dropped)
    return got


def _query(
    settings: Target, key: str, timeout_s: float, *, probe: dict[str, object] | None = None, all_replies: bool = False,
    skips: _Skips | None = None,
) -> list[tuple[str, bytes]]:
    """Query ``key`` until a reply or ``timeout_s``; ``probe`` receives ``reachable`` and ``where``."""
    if not timeout_s > 0:
        raise ConfigError(f"timeout_s must be > 0 seconds; got {timeout_s!r}")
    deadline = time.monotonic() + timeout_s
    try:
        bus, owned = _open(settings, wait_s=timeout_s)
    except TransportError as exc:  # a client whose endpoint never answered within timeout_s
        if "cannot connect" not in str(exc):
            raise
        if probe is not None:
            probe["reachable"] = False
            probe["where"] = ", ".join(settings.connect) if isinstance(settings, ZenohSettings) else str(settings)
        return []
    try:
        while True:  # declarations propagate asynchronously: retry until the deadline
            left = deadline - time.monotonic()
            wait_s = max(0.05, min(left, 0.5))
            got = (_bounded_get(bus, key, wait_s, skips) if all_replies else
                   bus.get(key, timeout_s=wait_s, max_replies=16, max_bytes=MAX_DOCUMENT_BYTES))
            if got or deadline - time.monotonic() <= 0:
                if probe is not None:
                    probe["reachable"] = bool(got) or bus.wait_connected(0.0)
                    probe["where"] = _where(bus)
                return got
            time.sleep(0.02)
    finally:
        if owned:
            bus.close()


class _Raise:
    """Marker: no ``default`` given to :func:`latest_model`."""


def _fetch(settings: Target, stream: str, timeout_s: float) -> tuple[dict[str, ModelUpdate], dict[str, object]]:
    """The current accepted model of each output of ``stream`` from the replies of a query on its model key."""
    check_stream_name(stream)
    probe: dict[str, object] = {}
    skips = _Skips(60.0)
    best: dict[str, ModelUpdate] = {}
    for key, payload in _query(settings, model_key(stream), timeout_s, probe=probe, all_replies=True, skips=skips):
        up = _check(key, payload, skips)
        if up is None:
            continue
        prev = best.get(up.output)
        if prev is None or recency(up) > recency(prev):
            best[up.output] = up
    return best, probe


def _nothing(stream: str, output: str | None, timeout_s: float, probe: dict[str, object],
             models: dict[str, ModelUpdate]) -> Exception:
    where = probe.get("where", "the endpoint")
    if not probe.get("reachable"):
        return NoDaemonError(
            f"no daemon reachable at {where}: nothing answered within {timeout_s:g} s "
            "(start `streamid daemon`, or pass the endpoint it listens on)"
        )
    if output is not None and models:
        return NoModelYetError(
            f"no model of output {output!r} of stream {stream!r} at {where}; outputs with a model: "
            f"{', '.join(printable(o, 80) for o in sorted(models))} (pass output=None or one of these)"
        )
    return NoModelYetError(
        f"no model of stream {stream!r} yet at {where}: the network answers, but no model was published "
        f"within {timeout_s:g} s (is a device publishing on streamid/{stream}/samples? a first model takes one window)"
    )


def latest_model(
    settings: Target, stream: str, timeout_s: float = 2.0, *, output: str | None = None, default: object = _Raise
) -> ModelUpdate | None:
    """The current model of ``stream`` (of one of its outputs) from the daemon's queryable.

    Parameters
    ----------
    settings
        Where the daemon is: an endpoint string such as ``"tcp/127.0.0.1:7447"``,
        :class:`ZenohSettings`, or an open :class:`Bus`.
    stream
        The stream's name.
    timeout_s
        How long to wait for an answer.
    output
        Which output's model (a stream with several outputs has one model per output);
        None: the only one, or the first in name order.  :func:`latest_models` gives all.
    default
        Returned instead of raising when there is no model (either reason); e.g. ``default=None``.

    Only accepted models are returned; replies that are malformed or name another stream
    are skipped (counted in the log warning).  Of several replies for one output (e.g.
    from two daemon lives), the one of the latest life wins, then the highest version.

    Raises
    ------
    NoDaemonError
        Nothing is reachable at the endpoint (no daemon, router or peer) within ``timeout_s``.
    NoModelYetError
        The network is reachable but no model of ``stream`` (or of ``output``) was published yet.
    """
    models, probe = _fetch(settings, stream, timeout_s)
    up = _pick(models, output)
    if up is not None:
        return up
    if default is not _Raise:
        return default  # type: ignore[return-value]
    raise _nothing(stream, output, timeout_s, probe, models)


def latest_models(settings: Target, stream: str, timeout_s: float = 2.0, *, default: Any = _Raise) -> dict[str, ModelUpdate]:
    """The current model of every output of ``stream``, by output name (see :func:`latest_model`).

    Raises
    ------
    NoDaemonError, NoModelYetError
        As :func:`latest_model`, unless ``default`` is given (returned instead).
    """
    models, probe = _fetch(settings, stream, timeout_s)
    if models:
        return dict(sorted(models.items()))
    if default is not _Raise:
        return default
    raise _nothing(stream, None, timeout_s, probe, models)


def latest_status(settings: Target, stream: str, timeout_s: float = 2.0) -> dict[str, Any] | None:
    """The current status document of ``stream`` (None if none within ``timeout_s``)."""
    for key, payload in _query(settings, status_key(stream), timeout_s):
        try:
            return parse_status(payload)
        except ModelFormatError as exc:
            _log.warning("invalid status from %s skipped: %s", printable(key, 200), exc)
    return None
