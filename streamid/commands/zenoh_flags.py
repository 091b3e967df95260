"""The Zenoh connection flags every command shares (``--mode``, ``--connect``, ``--listen``, ...)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from streamid.transport import MODES, ZenohSettings

__all__ = ["add_connection_flags", "settings_from_args"]


def add_connection_flags(
    parser: argparse.ArgumentParser,
    *,
    default_connect: Sequence[str] = (),
    default_listen: Sequence[str] = (),
    default_mode: str | None = None,
) -> None:
    """Add the shared Zenoh connection flags to ``parser``.

    Flags: ``--mode``, ``--connect ENDPOINT`` (repeatable), ``--listen
    ENDPOINT`` (repeatable), ``--zenoh-config FILE``, ``--multicast-scouting``,
    ``--connect-wait S``.  Without ``--mode`` (and ``default_mode``) a process
    that connects and listens nowhere is a Zenoh ``client`` (peers that only
    connect to a router never receive each other's messages), else a ``peer``.
    The default endpoints apply only when none of ``--connect``,
    ``--listen`` and ``--zenoh-config`` is given.
    """
    default_mode_text = default_mode or "client when --connect is given without --listen, else peer"
    group = parser.add_argument_group("zenoh connection")
    group.add_argument("--mode", choices=MODES, default=None,
                       help=f"Zenoh session mode (default: {default_mode_text}, or the --zenoh-config file's)")
    group.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                       help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; "
                            f"default: {' '.join(default_connect) or 'none'})")
    group.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                       help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; "
                            f"default: {' '.join(default_listen) or 'none'})")
    group.add_argument("--zenoh-config", default=None, metavar="FILE",
                       help="Zenoh JSON5 configuration file (access control, TLS, ...)")
    group.add_argument("--multicast-scouting", action="store_true",
                       help="enable Zenoh multicast scouting (off by default)")
    group.add_argument("--connect-wait", type=_seconds, default=None, metavar="S",
                       help="a client whose --connect endpoints do not answer yet retries for S seconds "
                            "(default: until stopped)")
    parser.set_defaults(_zenoh_default_connect=tuple(default_connect),
                        _zenoh_default_listen=tuple(default_listen),
                        _zenoh_default_mode=default_mode)


def settings_from_args(args: argparse.Namespace) -> ZenohSettings:
    """Build :class:`ZenohSettings` from flags added by :func:`add_connection_flags`."""
    config_file = getattr(args, "zenoh_config", None)
    explicit = args.connect is not None or args.listen is not None or config_file is not None
    if explicit:  # endpoints given (or a config file): no default endpoint is added
        connect = tuple(args.connect or ())
        listen = tuple(args.listen or ())
    else:
        connect = tuple(getattr(args, "_zenoh_default_connect", ()))
        listen = tuple(getattr(args, "_zenoh_default_listen", ()))
    mode = args.mode
    if mode is None and config_file is None:
        mode = getattr(args, "_zenoh_default_mode", None)  # None: client when connecting only, else peer
    return ZenohSettings(
        mode=mode,
        connect=tuple(connect),
        listen=tuple(listen),
        config_file=config_file,
        multicast_scouting=bool(getattr(args, "multicast_scouting", False)),
        connect_wait_s=getattr(args, "connect_wait", None),
    )


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number of seconds >= 0, e.g. 30; got {text!r}")
    return value
