"""Eclipse Zenoh transport: the only module of streamid that imports ``zenoh``.

Everything else talks to the bus through :class:`Bus`, whose payloads are
always ``bytes``.  The defaults are loopback-friendly and quiet: multicast
scouting is off unless asked for, and a session listens only on the endpoints
it is given (never on every interface), so peers meet through explicit
``--listen`` / ``--connect`` endpoints such as ``tcp/127.0.0.1:7447``.

Publishers of samples use BLOCK congestion control: with Zenoh's default
(DROP) a burst of puts can silently lose messages.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from streamid.errors import ConfigError, TransportError
from streamid.transport.endpoints import check_endpoint, explain_open_error
from streamid.transport.replies import GET_MAX_BYTES, GET_MAX_REPLIES, GET_QUEUE, Replies

__all__ = ["DEFAULT_ENDPOINT", "MODES", "ZenohSettings", "Bus", "BusPublisher", "CONNECT_RETRY_S", "GET_MAX_BYTES",
           "GET_MAX_REPLIES", "MAX_ATTACHMENT_BYTES", "Replies"]

_log = logging.getLogger(__name__)

#: The endpoint streamid's daemon listens on by default and clients connect to.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

#: Seconds between two attempts of a client session to reach its ``connect`` endpoints at open.
CONNECT_RETRY_S = 0.5

#: Accepted Zenoh session modes.
MODES: tuple[str, ...] = ("peer", "client", "router")

@dataclass(frozen=True)
class ZenohSettings:
    """How to open a Zenoh session.

    Parameters
    ----------
    mode : {"peer", "client", "router"} or None
        Zenoh session mode (a ``router`` session is a working Zenoh router).
        ``None`` (the default): the ``config_file``'s mode; without a file,
        ``client`` for a session that connects and listens nowhere, else ``peer``
        (:meth:`resolved_mode`).  Zenoh peers expect to reach each other
        directly: two peers that only connect to a router (or to a listening
        daemon) were never delivered each other's messages (eclipse-zenoh 1.10,
        measured), while clients are routed by what they connect to.
    connect : tuple of str
        Endpoints to connect to, e.g. ``("tcp/127.0.0.1:7447",)``.
    listen : tuple of str
        Endpoints to listen on. Empty means: listen nowhere (unless a
        ``config_file`` says otherwise); never all interfaces by default.
    config_file : str or None
        A Zenoh JSON5 configuration file (access control, TLS, ...).  It is
        loaded first; explicit ``connect``/``listen``/scouting values given
        here override it only when non-empty / when scouting is asked for.
    multicast_scouting : bool
        Enable multicast scouting (off by default: it sends on a multicast
        group and delays ``open`` by ~0.5 s).
    """

    mode: str | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    config_file: str | None = None
    multicast_scouting: bool = False
    #: Extra raw JSON5 key/value pairs inserted last (e.g. ``{"adminspace/enabled": "true"}``).
    extra: tuple[tuple[str, str], ...] = field(default=())
    #: How long opening a ``client`` session waits for one of ``connect`` to answer, retrying
    #: every :data:`CONNECT_RETRY_S` (None: until the :class:`Bus`'s ``stop`` event is set).
    #: A peer opens at once and connects in the background; a client cannot open alone.
    connect_wait_s: float | None = 10.0

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"zenoh mode must be one of {', '.join(MODES)}; got {self.mode!r}")
        object.__setattr__(self, "connect", tuple(self.connect))
        object.__setattr__(self, "listen", tuple(self.listen))
        for ep in self.connect:
            check_endpoint(ep, "connect")
        for ep in self.listen:
            check_endpoint(ep, "listen")
        if self.connect_wait_s is not None and not (
            isinstance(self.connect_wait_s, (int, float)) and 0 <= self.connect_wait_s < float("inf")
        ):
            raise ConfigError(f"connect_wait_s must be a finite number of seconds >= 0 or None (wait until "
                              f"stopped); got {self.connect_wait_s!r}")
        if self.config_file is not None and not Path(self.config_file).is_file():
            raise ConfigError(f"zenoh config file must be an existing JSON5 file; got {self.config_file!r}")

    def resolved_mode(self) -> str | None:
        """The mode the session opens in (None: the config file's)."""
        if self.mode is not None:
            return self.mode
        if self.config_file is not None:
            return None
        return "client" if self.connect and not self.listen else "peer"

    def with_max_message_bytes(self, n_bytes: int) -> ZenohSettings:
        """These settings with Zenoh's own bound on one received message (``transport/link/rx/max_message_size``).

        Zenoh drops a larger message before it is reassembled (silently: the
        receiver never sees it, the link stays up); the default is 1 GiB.
        """
        if isinstance(n_bytes, bool) or not isinstance(n_bytes, int) or n_bytes < 1024:
            raise ConfigError(f"max message size must be an integer number of bytes >= 1024; got {n_bytes!r}")
        return dataclasses.replace(self, extra=(*self.extra, ("transport/link/rx/max_message_size", str(n_bytes))))

    def to_config(self) -> zenoh.Config:
        """Build the :class:`zenoh.Config` these settings describe.

        Raises
        ------
        TransportError
            If the configuration file cannot be loaded or a value is refused by Zenoh.
        """
        try:
            if self.config_file is not None:
                conf = zenoh.Config.from_file(self.config_file)
            else:
                conf = zenoh.Config()
            mode = self.resolved_mode()
            if mode is not None:
                conf.insert_json5("mode", json.dumps(mode))
            # A file that leaves multicast scouting or the listen endpoints unset would get
            # Zenoh's own defaults: scouting on a multicast group and listening on every
            # interface.  streamid's rule is loopback unless configured otherwise, so both
            # are forced off unless the file (or a flag) says something.
            file_sets_scouting = (
                self.config_file is not None and conf.get_json("scouting/multicast/enabled") != "null"
            )
            if self.multicast_scouting or not file_sets_scouting:
                conf.insert_json5(
                    "scouting/multicast/enabled", "true" if self.multicast_scouting else "false"
                )
            file_sets_listen = (
                self.config_file is not None
                and conf.get_json("listen/endpoints") != zenoh.Config().get_json("listen/endpoints")
            )
            if self.listen or not file_sets_listen:
                conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            if self.connect or self.config_file is None:
                conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
            # Zenoh's shared-memory transport (on by default) maps a 16 MiB pool in /dev/shm per
            # process and removes it at exit; the streamid command leaves with os._exit (see
            # streamid.commands.main), which skipped that and left ~35 MB behind per `streamid demo`.
            # Loopback TCP carries 80k 16-kB messages/s here, far above what decoding takes in.
            # Off unless `extra` turns it on (a file cannot: its "true" is Zenoh's default).
            conf.insert_json5("transport/shared_memory/enabled", "false")
            for key, value in self.extra:
                conf.insert_json5(key, value)
        except zenoh.ZError as exc:
            raise TransportError(f"zenoh configuration refused ({exc}); settings: {self}") from exc
        return conf


Callback = Callable[[str, bytes], None]
#: ``(key, payload, timestamp_ns or None, attachment or None)``: :meth:`Bus.subscribe_meta`'s callback.
MetaCallback = Callable[[str, bytes, "int | None", "bytes | None"], None]
#: A sample's attachment longer than this is not copied out of Zenoh (given as None).
MAX_ATTACHMENT_BYTES = 256
QueryHandler = Callable[[str], "bytes | Sequence[bytes] | None"]


class BusPublisher:
    """A declared publisher on one key: ``put(bytes)``, ``has_subscribers()``."""

    def __init__(self, publisher: Any, key: str, forget: Callable[[Any], None] | None = None) -> None:
        self._pub = publisher
        self.key = key
        self._forget = forget

    def put(self, payload: bytes) -> None:
        """Publish ``payload`` (``bytes``/``bytearray``) on this publisher's key."""
        if not isinstance(payload, (bytes, bytearray)):
            raise TypeError(f"payload must be bytes; got {type(payload).__name__}")
        self._pub.put(bytes(payload) if isinstance(payload, bytearray) else payload)

    def has_subscribers(self) -> bool:
        """Whether a subscriber matching this key is known to exist right now."""
        return bool(self._pub.matching_status.matching)

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Poll :meth:`has_subscribers` until true or ``timeout_s`` passed; return the final state."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.has_subscribers():
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)

    def close(self) -> None:
        """Undeclare the publisher (idempotent)."""
        try:
            self._pub.undeclare()
        except zenoh.ZError:
            pass
        if self._forget is not None:
            self._forget(self._pub)
            self._forget = None


class _Handle:
    """An undeclarable subscription or queryable."""

    def __init__(self, entity: Any, forget: Callable[[Any], None] | None = None) -> None:
        self._entity = entity
        self._forget = forget

    def close(self) -> None:
        try:
            self._entity.undeclare()
        except zenoh.ZError:
            pass
        if self._forget is not None:  # the session stops keeping it (entities declared and closed often)
            self._forget(self._entity)
            self._forget = None


class Bus:
    """A Zenoh session with ``bytes`` payloads.

    Use as a context manager::

        with Bus(ZenohSettings(listen=("tcp/127.0.0.1:7447",))) as bus:
            pub = bus.publisher("streamid/demo/samples")
            pub.put(payload)

    Callbacks run on Zenoh's threads; an exception escaping a callback is
    logged (with the key) and swallowed so that the session keeps running.
    """

    def __init__(self, settings: ZenohSettings | None = None, *, stop: threading.Event | None = None) -> None:
        self.settings = settings if settings is not None else ZenohSettings()
        self._session = self._open(self.settings, stop)
        self._lock = threading.Lock()
        self._entities: list[Any] = []
        self._closed = False

    @staticmethod
    def _open(settings: ZenohSettings, stop: threading.Event | None) -> Any:
        """``zenoh.open``; a client nothing answers yet retries until ``connect_wait_s`` or ``stop``.

        Raises TransportError (with the explanation of the last failure) when it gives up.
        """
        wait_s = settings.connect_wait_s
        deadline = None if wait_s is None else time.monotonic() + wait_s
        waited = False
        while True:
            conf = settings.to_config()
            try:
                session = zenoh.open(conf)
            except zenoh.ZError as exc:
                text = str(exc)
                mode = settings.resolved_mode() or json.loads(conf.get_json("mode") or '"peer"')  # (or the file's)
                retry = "Unable to connect" in text and mode == "client"
                left = None if deadline is None else deadline - time.monotonic()
                if not retry or (left is not None and left <= 0) or (stop is not None and stop.is_set()):
                    raise TransportError(explain_open_error(text, settings)) from exc
                if not waited:
                    waited = True
                    where = ", ".join(settings.connect) or ", ".join(json.loads(conf.get_json("connect/endpoints") or "[]"))
                    _log.warning("nothing answers at %s yet; retrying every %g s %s", where,
                                 CONNECT_RETRY_S, "until stopped" if left is None else f"for {left:.0f} s")
                pause = CONNECT_RETRY_S if left is None else min(CONNECT_RETRY_S, max(0.0, left))
                if stop is not None:
                    stop.wait(pause)
                else:
                    time.sleep(pause)
                continue
            if waited:
                _log.warning("connected to %s", ", ".join(settings.connect) or "the configured endpoints")
            return session

    # -- context manager -------------------------------------------------
    def __enter__(self) -> Bus:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @property
    def zid(self) -> str:
        """This session's Zenoh id."""
        return str(self._session.zid())

    def _check_open(self) -> None:
        if self._closed:
            raise TransportError("the zenoh session is closed; open a new Bus")

    def _keep(self, entity: Any) -> None:
        with self._lock:
            self._entities.append(entity)

    def _drop(self, entity: Any) -> None:
        with self._lock:
            try:
                self._entities.remove(entity)
            except ValueError:
                pass

    # -- pub/sub ---------------------------------------------------------
    def subscribe(
        self,
        key_expr: str,
        callback: Callback,
        *,
        max_payload_bytes: int | None = None,
        on_too_large: Callable[[str, int], None] | None = None,
    ) -> _Handle:
        """Call ``callback(key, payload_bytes)`` for every sample put on ``key_expr``.

        A payload longer than ``max_payload_bytes`` is not copied out of Zenoh nor
        given to ``callback``: ``on_too_large(key, length)`` is called instead.
        Returns a handle whose ``close()`` undeclares the subscription.
        """
        return self._declare_sub(key_expr, lambda key, sample: callback(key, sample.payload.to_bytes()),
                                 max_payload_bytes, on_too_large)

    def subscribe_meta(self, key_expr: str, callback: MetaCallback, *, max_payload_bytes: int | None = None,
                       on_too_large: Callable[[str, int], None] | None = None) -> _Handle:
        """:meth:`subscribe`, the callback also given the sample's Zenoh timestamp (int ns since the UNIX epoch, None
        when the publishing side set none) and its attachment (None: none, or over :data:`MAX_ATTACHMENT_BYTES`)."""

        def deliver(key: str, sample: Any) -> None:
            ts, att = sample.timestamp, sample.attachment
            t_ns = None if ts is None else _timestamp_ns(ts)
            keep = att is not None and len(att) <= MAX_ATTACHMENT_BYTES
            callback(key, sample.payload.to_bytes(), t_ns, att.to_bytes() if keep else None)

        return self._declare_sub(key_expr, deliver, max_payload_bytes, on_too_large)

    def _declare_sub(self, key_expr: str, deliver: Callable[[str, Any], None], max_payload_bytes: int | None,
                     on_too_large: Callable[[str, int], None] | None) -> _Handle:
        self._check_open()

        def _on_sample(sample: Any) -> None:
            key = str(sample.key_expr)
            try:
                if sample.kind != zenoh.SampleKind.PUT:
                    return
                if max_payload_bytes is not None:
                    size = len(sample.payload)
                    if size > max_payload_bytes:
                        if on_too_large is not None:
                            on_too_large(key, size)
                        return
                deliver(key, sample)
            except Exception:  # noqa: BLE001 - a callback must not kill zenoh's thread
                _log.exception("subscriber callback failed on key %s", key)

        try:
            sub = self._session.declare_subscriber(key_expr, _on_sample)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot subscribe: key expression must be a valid Zenoh key expression such as "
                                 f"'streamid/**'; got {key_expr!r} ({exc})") from exc
        self._keep(sub)
        return _Handle(sub, self._drop)

    # -- liveliness --------------------------------------------------------
    def liveliness_token(self, key: str) -> _Handle:
        """Declare a liveliness token on ``key``: alive while this session lives and the handle is open.

        Zenoh withdraws it when ``close()`` is called, the session ends or its transport is lost
        (a killed process: as soon as its TCP connection closes; a silent link: after the lease).
        """
        self._check_open()
        try:
            token = self._session.liveliness().declare_token(key)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot declare liveliness token: key must be a Zenoh key without "
                                 f"wildcards such as 'streamid/@daemons/a/1'; got {key!r} ({exc})") from exc
        self._keep(token)
        return _Handle(token, self._drop)

    def liveliness_subscribe(self, key_expr: str, callback: Callable[[str, bool], None]) -> _Handle:
        """Call ``callback(key, alive)`` for every token on ``key_expr``: the ones alive now, then each change."""
        self._check_open()

        def _on_change(sample: Any) -> None:
            key = str(sample.key_expr)
            try:
                callback(key, sample.kind == zenoh.SampleKind.PUT)
            except Exception:  # noqa: BLE001 - a callback must not kill zenoh's thread
                _log.exception("liveliness callback failed on key %s", key)

        try:
            sub = self._session.liveliness().declare_subscriber(key_expr, _on_change, history=True)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot subscribe to liveliness: key expression must be a valid Zenoh key "
                                 f"expression such as 'streamid/@daemons/*/*'; got {key_expr!r} ({exc})") from exc
        self._keep(sub)
        return _Handle(sub, self._drop)

    def publisher(self, key: str, block: bool = True, *, express: bool = False) -> BusPublisher:
        """Declare a publisher on ``key``.

        ``block=True`` (default, for samples) uses BLOCK congestion control so
        nothing is dropped when queues fill; ``block=False`` uses DROP (for
        status or latest-value traffic that must never stall the caller).
        """
        self._check_open()
        cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        try:
            pub = self._session.declare_publisher(key, congestion_control=cc, express=express)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot declare publisher: key must be a Zenoh key without wildcards such "
                                 f"as 'streamid/demo/samples'; got {key!r} ({exc})") from exc
        self._keep(pub)
        return BusPublisher(pub, key, self._drop)

    def put(self, key: str, payload: bytes, block: bool = True, *, attachment: bytes | None = None) -> None:
        """One-off put of ``payload`` (and ``attachment``) on ``key`` (prefer :meth:`publisher` for streams)."""
        self._check_open()
        cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        try:
            self._session.put(key, bytes(payload), congestion_control=cc, attachment=attachment)
        except zenoh.ZError as exc:
            raise TransportError(f"put on {key!r} failed ({exc})") from exc

    # -- query/reply -----------------------------------------------------
    def queryable(self, key: str, handler: QueryHandler) -> _Handle:
        """Answer queries on ``key``: ``handler(query_key) -> bytes | list of bytes | None``.

        A ``None`` result sends no reply, a list one reply per item (e.g. the model of
        each output of a stream).  Replies are sent on the queried key when it is
        concrete, else on ``key``.
        """
        self._check_open()

        def _on_query(query: Any) -> None:
            qkey = str(query.key_expr)
            try:
                payload = handler(qkey)
                reply_key = key if ("*" in qkey or "$" in qkey) else qkey
                for item in [payload] if isinstance(payload, (bytes, bytearray)) else payload or ():
                    query.reply(reply_key, bytes(item))
            except Exception:  # noqa: BLE001
                _log.exception("queryable handler failed on key %s", qkey)

        try:
            qbl = self._session.declare_queryable(key, _on_query)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot declare queryable on {key!r} ({exc})") from exc
        self._keep(qbl)
        return _Handle(qbl, self._drop)

    def wait_connected(self, timeout_s: float) -> bool:
        """Wait until this session has a link to at least one peer or router.

        A session that connects to an endpoint opens at once and links in the
        background; anything published before the link is up is not seen here.
        Returns whether a link exists (``False`` after ``timeout_s``).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            info = self._session.info
            if list(info.peers_zid()) or list(info.routers_zid()):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    def get(self, key_expr: str, timeout_s: float = 1.0, *, all_replies: bool = False,
            max_replies: int = GET_MAX_REPLIES, max_bytes: int = GET_MAX_BYTES,
            max_reply_bytes: int | None = None) -> Replies:
        """Query ``key_expr``; return the successful replies as ``(key, payload)``.

        Waits at most ``timeout_s``; error replies are skipped.  Zenoh keeps one reply per
        key by default; ``all_replies=True`` keeps every one (e.g. one per output on a model key).

        Bounded whoever answers: at most ``max_replies`` replies of at most ``max_bytes`` payload
        bytes together are kept (a reply larger than ``max_reply_bytes``, default ``max_bytes``, is
        never kept); the others are measured without being copied and counted in
        :attr:`Replies.dropped` / :attr:`Replies.dropped_bytes` until the query ends (``timeout_s``).
        Zenoh holds at most a few replies for this get at a time.
        """
        self._check_open()
        if not timeout_s > 0:
            raise ConfigError(f"timeout_s must be > 0 seconds; got {timeout_s!r}")
        one = max_bytes if max_reply_bytes is None else min(max_reply_bytes, max_bytes)
        try:
            replies = self._session.get(key_expr, zenoh.handlers.FifoChannel(GET_QUEUE), timeout=float(timeout_s),
                                        consolidation=zenoh.ConsolidationMode.NONE if all_replies else None)
        except zenoh.ZError as exc:
            raise TransportError(f"get on {key_expr!r} failed ({exc})") from exc
        out = Replies()
        kept_bytes = 0
        for reply in replies:  # the handler ends when every replier answered or the timeout hit
            ok = reply.ok
            if ok is None:
                continue
            size = len(ok.payload)
            if len(out) >= max_replies or size > one or kept_bytes + size > max_bytes:
                out.dropped += 1
                out.dropped_bytes += size
                continue
            out.append((str(ok.key_expr), ok.payload.to_bytes()))
            kept_bytes += size
        return out

    # -- introspection ---------------------------------------------------
    def peers(self) -> list[str]:
        """Zenoh ids of the peers this session is connected to."""
        info = self._session.info
        return [str(z) for z in info.peers_zid()]

    def routers(self) -> list[str]:
        """Zenoh ids of the routers this session is connected to."""
        info = self._session.info
        return [str(z) for z in info.routers_zid()]

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            entities, self._entities = self._entities, []
        for ent in reversed(entities):
            try:
                ent.undeclare()
            except Exception:  # noqa: BLE001 - already undeclared by the user
                pass
        try:
            self._session.close()
        except zenoh.ZError:
            pass


def _timestamp_ns(ts: Any) -> int:
    """A Zenoh timestamp's time as int ns since the UNIX epoch (eclipse-zenoh 1.x: an NTP64 object's ``as_nanos``)."""
    return int(ts.get_time_as_ntp64().as_nanos())
