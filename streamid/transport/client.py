"""Client side of the daemon: receive identified models over Zenoh.

>>> from streamid.transport.client import ModelSubscriber, latest_model
>>> from streamid.transport import ZenohSettings
>>> zs = ZenohSettings(connect=("tcp/127.0.0.1:7447",))
>>> with ModelSubscriber(zs, "bench1", lambda up: print(up.version, up.model.lags)):   # doctest: +SKIP
...     ...
>>> up = latest_model(zs, "bench1", timeout_s=2.0)                                     # doctest: +SKIP
>>> yhat = up.model.simulate(u, y[: up.model.max_lag])                                  # doctest: +SKIP

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

from streamid.transport.updates import ModelUpdate, parse_model_update
from streamid.wire.documents import parse_status
from streamid.errors import ConfigError, ModelFormatError
from streamid.wire.keys import PREFIX, check_stream_name, model_key, status_key
from streamid.transport.zenoh_bus import Bus, ZenohSettings, _Handle

__all__ = ["ModelSubscriber", "ModelUpdate", "latest_model", "latest_status"]

_log = logging.getLogger(__name__)


def _open(bus_or_settings: Bus | ZenohSettings) -> tuple[Bus, bool]:
    if isinstance(bus_or_settings, Bus):
        return bus_or_settings, False
    if isinstance(bus_or_settings, ZenohSettings):
        return Bus(bus_or_settings), True
    raise ConfigError(f"expected ZenohSettings or an open Bus; got {type(bus_or_settings).__name__}")


class ModelSubscriber:
    """Hand every new model of a stream to ``callback``.

    Parameters
    ----------
    settings
        :class:`~streamid.transport.zenoh_bus.ZenohSettings` (a session is opened and
        closed with the subscriber) or an open :class:`~streamid.transport.zenoh_bus.Bus`.
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
        settings: ZenohSettings | Bus,
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


def _query(settings: ZenohSettings | Bus, key: str, timeout_s: float) -> list[tuple[str, bytes]]:
    if not timeout_s > 0:
        raise ConfigError(f"timeout_s must be > 0 seconds; got {timeout_s!r}")
    bus, owned = _open(settings)
    try:
        deadline = time.monotonic() + timeout_s
        while True:  # declarations propagate asynchronously: retry until the deadline
            left = deadline - time.monotonic()
            got = bus.get(key, timeout_s=max(0.05, min(left, 0.5)))
            if got or deadline - time.monotonic() <= 0:
                return got
            time.sleep(0.02)
    finally:
        if owned:
            bus.close()


def latest_model(settings: ZenohSettings | Bus, stream: str, timeout_s: float = 2.0) -> ModelUpdate | None:
    """The current model of ``stream`` from the daemon's queryable (None if none within ``timeout_s``)."""
    best: ModelUpdate | None = None
    for key, payload in _query(settings, model_key(stream), timeout_s):
        try:
            up = parse_model_update(payload)
        except ModelFormatError as exc:
            _log.warning("invalid model update from %s skipped: %s", key, exc)
            continue
        if best is None or up.version > best.version:
            best = up
    return best


def latest_status(settings: ZenohSettings | Bus, stream: str, timeout_s: float = 2.0) -> dict | None:
    """The current status document of ``stream`` (None if none within ``timeout_s``)."""
    for key, payload in _query(settings, status_key(stream), timeout_s):
        try:
            return parse_status(payload)
        except ModelFormatError as exc:
            _log.warning("invalid status from %s skipped: %s", key, exc)
    return None
