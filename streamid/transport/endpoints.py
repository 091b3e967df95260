"""Zenoh endpoints and session-opening errors, in words (no ``zenoh`` import: :mod:`streamid.transport.zenoh_bus` is the adapter)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Protocol

from streamid.errors import ConfigError

__all__ = ["SessionEndpoints", "check_endpoint", "explain_open_error"]


class SessionEndpoints(Protocol):
    """What :func:`explain_open_error` reads of a session's settings
    (:class:`~streamid.transport.zenoh_bus.ZenohSettings`, which imports this module, not the reverse)."""

    @property
    def listen(self) -> Sequence[str]: ...

    @property
    def connect(self) -> Sequence[str]: ...

    def resolved_mode(self) -> str | None: ...

_ENDPOINT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe")


def check_endpoint(endpoint: str, what: str) -> str:
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise ConfigError(
            f"{what} endpoint must be a Zenoh locator '<protocol>/<address>' such as "
            f"'tcp/127.0.0.1:7447'; got {endpoint!r}"
        )
    proto = endpoint.split("/", 1)[0]
    if proto not in _ENDPOINT_PROTOCOLS:
        raise ConfigError(
            f"{what} endpoint protocol must be one of {', '.join(_ENDPOINT_PROTOCOLS)}; "
            f"got {proto!r} in {endpoint!r}"
        )
    return endpoint


_RUST_WHERE = re.compile(r"\s*at /\S+\.rs:\d+\.?")
_BOUND_TO = re.compile(r"bound to ([a-z-]+/[^\s:\]]+:\d+)")


def explain_open_error(message: str, settings: SessionEndpoints) -> str:
    """One sentence for a failed ``zenoh.open``: the endpoint, what is wrong and the flag that changes it.

    Zenoh's own text (with Rust source paths) is reduced to its first clause.
    """
    text = _RUST_WHERE.sub("", message).strip().rstrip(".")
    if "Address already in use" in text or "address in use" in text.lower():
        m = _BOUND_TO.search(text)
        ep = m.group(1) if m else (", ".join(settings.listen) or "the listen endpoint")
        return (
            f"cannot listen on {ep}: the address is already in use (another streamid daemon or router running?); "
            f"stop that process or choose another endpoint with --listen, e.g. --listen tcp/127.0.0.1:7448"
        )
    if "Unable to connect" in text:
        eps = ", ".join(settings.connect) or "the connect endpoints"
        return (
            f"cannot open zenoh session: cannot connect to {eps}: nothing answers there, or it refused this session "
            f"(mode {settings.resolved_mode() or 'from the config file'}; with access control or TLS, check the credentials and "
            "certificates of --zenoh-config); start `streamid daemon` or `streamid router` there, or point --connect "
            "at where one listens"
        )
    if "Can not create a new" in text and "listener" in text:
        eps = ", ".join(settings.listen) or "the listen endpoint"
        return f"cannot listen on {eps} ({text}); choose another endpoint with --listen, e.g. --listen tcp/127.0.0.1:7448"
    return f"cannot open zenoh session ({text}); listen {list(settings.listen)}, connect {list(settings.connect)}, mode {settings.resolved_mode()}"
