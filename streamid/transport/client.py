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
:class:`~streamid.engine.Model` rebuilt from the published JSON, its version,
the window it was fitted on and its validation metrics.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Union

from streamid.transport.updates import ModelUpdate, parse_model_update
from streamid.wire.documents import parse_status
from streamid.errors import ConfigError, ModelFormatError, NoDaemonError, NoModelYetError
from streamid.wire.keys import PREFIX, check_stream_name, model_key, status_key
from streamid.transport.zenoh_bus import Bus, ZenohSettings, _Handle

__all__ = ["ModelSubscriber", "ModelUpdate", "NoDaemonError", "NoModelYetError", "Target", "latest_model", "latest_status"]

_log = logging.getLogger(__name__)


#: Where to reach the daemon: an endpoint string, settings, or an open session.
Target = Union[str, ZenohSettings, Bus]


def _open(bus_or_settings: Target) -> tuple[Bus, bool]:
    if isinstance(bus_or_settings, Bus):
        return bus_or_settings, False
    if isinstance(bus_or_settings, str):
        bus_or_settings = ZenohSettings(connect=(bus_or_settings,))  # checks the endpoint's form
    if isinstance(bus_or_settings, ZenohSettings):
        return Bus(bus_or_settings), True
    raise ConfigError(
        "where to connect must be an endpoint string such as 'tcp/127.0.0.1:7447', ZenohSettings or an open Bus; "
        f"got {type(bus_or_settings).__name__} {bus_or_settings!r}"
    )


def _where(bus: Bus) -> str:
    s = bus.settings
    return ", ".join(s.connect) or ", ".join(f"listening on {e}" for e in s.listen) or "the --zenoh-config endpoints"


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
        ``callback(update: ModelUpdate)``, called on a Zenoh thread, in
        increasing version order per stream (older or repeated versions are
        skipped).  An exception it raises is logged, never propagated.
    fetch_latest
        Query the current model at start, so a late subscriber gets it at once.
    latest_timeout_s
        How long that first query waits.

    Attributes
    ----------
    latest : dict
        Newest update per stream.
    errors : int
        Payloads that were not valid model updates (skipped).
    """

    def __init__(
        self,
        settings: Target,
        stream: str,
        callback: Callable[[ModelUpdate], object],
        *,
        fetch_latest: bool = True,
        latest_timeout_s: float = 1.0,
    ) -> None:
        if stream != "*":
            check_stream_name(stream)
        self.stream = stream
        self.callback = callback
        self.latest: dict[str, ModelUpdate] = {}
        self.errors = 0
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._order = threading.RLock()
        self._bus, self._owned = _open(settings)
        key = f"{PREFIX}/*/model" if stream == "*" else model_key(stream)
        try:
            self._sub: _Handle | None = self._bus.subscribe(key, self._on_payload)
            if fetch_latest:
                for _k, payload in self._bus.get(key, timeout_s=latest_timeout_s):
                    self._on_payload(_k, payload)
        except BaseException:
            self.close()
            raise

    def _on_payload(self, key: str, payload: bytes) -> None:
        try:
            up = parse_model_update(payload)
        except ModelFormatError as exc:
            with self._lock:
                self.errors += 1
            _log.warning("invalid model update on %s skipped: %s", key, exc)
            return
        with self._order:  # one delivery at a time, in version order
            with self._cond:
                prev = self.latest.get(up.stream)
                if prev is not None and up.version <= prev.version:
                    return
                self.latest[up.stream] = up
                self._cond.notify_all()
            try:
                self.callback(up)
            except Exception:  # noqa: BLE001 - the user's callback must not kill zenoh's thread
                _log.exception("ModelSubscriber callback failed on version %d of %s", up.version, up.stream)

    def wait_for_version(self, version: int, timeout_s: float, stream: str | None = None) -> ModelUpdate | None:
        """Block until a model of at least ``version`` arrived (None on timeout)."""
        name = stream or self.stream
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                up = self.latest.get(name)
                if up is not None and up.version >= version:
                    return up
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def close(self) -> None:
        """Undeclare the subscription (and close the session if it was opened here)."""
        sub = getattr(self, "_sub", None)
        if sub is not None:
            sub.close()
            self._sub = None
        if self._owned:
            self._bus.close()

    def __enter__(self) -> ModelSubscriber:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _query(settings: Target, key: str, timeout_s: float, *, probe: dict[str, object] | None = None) -> list[tuple[str, bytes]]:
    """Query ``key`` until a reply or ``timeout_s``; ``probe`` receives ``reachable`` and ``where``."""
    if not timeout_s > 0:
        raise ConfigError(f"timeout_s must be > 0 seconds; got {timeout_s!r}")
    bus, owned = _open(settings)
    try:
        deadline = time.monotonic() + timeout_s
        while True:  # declarations propagate asynchronously: retry until the deadline
            left = deadline - time.monotonic()
            got = bus.get(key, timeout_s=max(0.05, min(left, 0.5)))
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


def latest_model(
    settings: Target, stream: str, timeout_s: float = 2.0, *, default: object = _Raise
) -> ModelUpdate | None:
    """The current model of ``stream`` from the daemon's queryable.

    Parameters
    ----------
    settings
        Where the daemon is: an endpoint string such as ``"tcp/127.0.0.1:7447"``,
        :class:`ZenohSettings`, or an open :class:`Bus`.
    stream
        The stream's name.
    timeout_s
        How long to wait for an answer.
    default
        Returned instead of raising when there is no model (either reason); e.g. ``default=None``.

    Raises
    ------
    NoDaemonError
        Nothing is reachable at the endpoint (no daemon, router or peer) within ``timeout_s``.
    NoModelYetError
        The network is reachable but no model of ``stream`` was published yet.
    """
    if stream != "*":
        check_stream_name(stream)
    best: ModelUpdate | None = None
    probe: dict[str, object] = {}
    for key, payload in _query(settings, model_key(stream), timeout_s, probe=probe):
        try:
            up = parse_model_update(payload)
        except ModelFormatError as exc:
            _log.warning("invalid model update from %s skipped: %s", key, exc)
            continue
        if best is None or up.version > best.version:
            best = up
    if best is not None:
        return best
    if default is not _Raise:
        return default  # type: ignore[return-value]
    where = probe.get("where", "the endpoint")
    if not probe.get("reachable"):
        raise NoDaemonError(
            f"no daemon reachable at {where}: nothing answered within {timeout_s:g} s "
            "(start `streamid daemon`, or pass the endpoint it listens on)"
        )
    raise NoModelYetError(
        f"no model of stream {stream!r} yet at {where}: the network answers, but no model was published "
        f"within {timeout_s:g} s (is a device publishing on streamid/{stream}/samples? a first model takes one window)"
    )


def latest_status(settings: Target, stream: str, timeout_s: float = 2.0) -> dict | None:
    """The current status document of ``stream`` (None if none within ``timeout_s``)."""
    for key, payload in _query(settings, status_key(stream), timeout_s):
        try:
            return parse_status(payload)
        except ModelFormatError as exc:
            _log.warning("invalid status from %s skipped: %s", key, exc)
    return None
