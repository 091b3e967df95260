"""Zenoh key expressions used by streamid.

Every stream lives under ``streamid/<stream>/``:

==========================  =====================================================
``streamid/<s>/samples``    sample batches carrying inputs and outputs together
``streamid/<s>/u``          sample batches carrying inputs only (e.g. from a DAC)
``streamid/<s>/y``          sample batches carrying outputs only (e.g. a sensor)
``streamid/<s>/model``      accepted models (JSON, ``streamid.model-update/1``)
``streamid/<s>/rejected``   rejected challengers (JSON, ``streamid.model-update/1``)
``streamid/<s>/status``     stream status (JSON, ``streamid.status/1``)
==========================  =====================================================

A stream name is one Zenoh chunk: 1-128 characters from ``A-Z a-z 0-9 _ - .``
(no ``/``, no wildcard), so it is also a safe file-name component.

Daemons sharing the streams (:mod:`streamid.daemon.sharing`) also use keys whose
second chunk starts with ``@`` (a Zenoh *verbatim* chunk: no wildcard matches it,
so ``streamid/*/*`` and ``streamid/**`` subscribers, recorders included, never see them):

=======================================  ==============================================
``streamid/@daemons/<id>/<epoch>``       liveliness token: a sharing daemon's life
``streamid/@claims/<s>/<id>/<epoch>``    liveliness token: that life serves (or claims) ``s``
``streamid/@state/<s>``                  the serving daemon's state of ``s`` (JSON, for its successor)
=======================================  ==============================================
"""

from __future__ import annotations

import re

from streamid.errors import ConfigError

__all__ = [
    "PREFIX",
    "KINDS",
    "SAMPLE_KINDS",
    "DOCUMENT_KINDS",
    "STREAM_NAME_RULE",
    "ALL_SAMPLES",
    "check_stream_name",
    "is_valid_stream_name",
    "stream_key",
    "samples_key",
    "u_key",
    "y_key",
    "model_key",
    "rejected_key",
    "status_key",
    "parse_key",
    "MEMBERS_ALL",
    "CLAIMS_ALL",
    "HANDOFF_ALL",
    "member_key",
    "claim_key",
    "handoff_key",
    "parse_life_key",
]

PREFIX = "streamid"
#: Every kind of key under a stream.
KINDS: tuple[str, ...] = ("samples", "u", "y", "model", "rejected", "status")
#: The kinds that carry sample batches.
SAMPLE_KINDS: tuple[str, ...] = ("samples", "u", "y")
#: The kinds that carry the daemon's JSON documents (model updates and status).
DOCUMENT_KINDS: tuple[str, ...] = ("model", "rejected", "status")
#: Key expressions matching every sample batch of every stream.
ALL_SAMPLES: tuple[str, ...] = tuple(f"{PREFIX}/*/{k}" for k in SAMPLE_KINDS)

#: Liveliness key expressions of every sharing daemon's life and of every claim; every handed-off state.
MEMBERS_ALL = f"{PREFIX}/@daemons/*/*"
CLAIMS_ALL = f"{PREFIX}/@claims/*/*/*"
HANDOFF_ALL = f"{PREFIX}/@state/*"
_LIFE_RE = re.compile(r"[0-9A-Za-z][0-9A-Za-z._-]{0,63}")

STREAM_NAME_RULE = "1 to 128 characters from A-Z a-z 0-9 _ - . (not '.' or '..')"
_STREAM_RE = re.compile(r"[A-Za-z0-9_.\-]{1,128}")


def is_valid_stream_name(name: object) -> bool:
    """Whether ``name`` is an accepted stream name (see :data:`STREAM_NAME_RULE`)."""
    return (
        isinstance(name, str)
        and _STREAM_RE.fullmatch(name) is not None
        and name not in (".", "..")
    )


def check_stream_name(name: object) -> str:
    """Return ``name`` if it is a valid stream name, else raise :class:`ConfigError`."""
    if not is_valid_stream_name(name):
        raise ConfigError(f"stream name must be {STREAM_NAME_RULE}; got {name!r}")
    return name  # type: ignore[return-value]


def stream_key(stream: str, kind: str) -> str:
    """``streamid/<stream>/<kind>`` with both parts checked."""
    check_stream_name(stream)
    if kind not in KINDS:
        raise ConfigError(f"key kind must be one of {', '.join(KINDS)}; got {kind!r}")
    return f"{PREFIX}/{stream}/{kind}"


def samples_key(stream: str) -> str:
    """Key of combined input/output sample batches: ``streamid/<stream>/samples``."""
    return stream_key(stream, "samples")


def u_key(stream: str) -> str:
    """Key of input-only sample batches: ``streamid/<stream>/u``."""
    return stream_key(stream, "u")


def y_key(stream: str) -> str:
    """Key of output-only sample batches: ``streamid/<stream>/y``."""
    return stream_key(stream, "y")


def model_key(stream: str) -> str:
    """Key of published models: ``streamid/<stream>/model``."""
    return stream_key(stream, "model")


def rejected_key(stream: str) -> str:
    """Key of rejected challengers (``"accepted": false`` model updates): ``streamid/<stream>/rejected``."""
    return stream_key(stream, "rejected")


def status_key(stream: str) -> str:
    """Key of the stream status: ``streamid/<stream>/status``."""
    return stream_key(stream, "status")


def parse_key(key: str) -> tuple[str, str]:
    """Split ``streamid/<stream>/<kind>`` into ``(stream, kind)``.

    Raises
    ------
    ConfigError
        If ``key`` is not of that form with a valid stream name and known kind.
    """
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) != 3 or parts[0] != PREFIX:
        raise ConfigError(
            f"key must be of the form '{PREFIX}/<stream>/<kind>' with kind in "
            f"{', '.join(KINDS)}; got {key!r}"
        )
    _, stream, kind = parts
    if not is_valid_stream_name(stream):
        raise ConfigError(f"stream name in key {key!r} must be {STREAM_NAME_RULE}; got {stream!r}")
    if kind not in KINDS:
        raise ConfigError(f"key kind must be one of {', '.join(KINDS)}; got {kind!r} in {key!r}")
    return stream, kind


def member_key(daemon: str, epoch_ns: int) -> str:
    """Liveliness key of a sharing daemon's life: ``streamid/@daemons/<daemon>/<epoch_ns>``."""
    return f"{PREFIX}/@daemons/{_life(daemon, epoch_ns)}"


def claim_key(stream: str, daemon: str, epoch_ns: int) -> str:
    """Liveliness key of a daemon life's claim on a stream: ``streamid/@claims/<stream>/<daemon>/<epoch_ns>``."""
    return f"{PREFIX}/@claims/{check_stream_name(stream)}/{_life(daemon, epoch_ns)}"


def handoff_key(stream: str) -> str:
    """Key of the serving daemon's state of a stream, for the daemon that takes it over: ``streamid/@state/<stream>``."""
    return f"{PREFIX}/@state/{check_stream_name(stream)}"


def _life(daemon: str, epoch_ns: int) -> str:
    if not isinstance(daemon, str) or not _LIFE_RE.fullmatch(daemon):
        raise ConfigError(f"daemon id must be 1-64 letters, digits, '.', '_' or '-'; got {daemon!r}")
    if isinstance(epoch_ns, bool) or not isinstance(epoch_ns, int) or epoch_ns < 0:
        raise ConfigError(f"epoch must be an integer number of ns >= 0; got {epoch_ns!r}")
    return f"{daemon}/{epoch_ns}"


def parse_life_key(key: str) -> tuple[str | None, str, int] | None:
    """``(stream or None, daemon, epoch_ns)`` of a member or claim key; None if it is not one."""
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) == 4 and parts[:2] == [PREFIX, "@daemons"]:
        stream, daemon, epoch = None, parts[2], parts[3]
    elif len(parts) == 5 and parts[:2] == [PREFIX, "@claims"] and is_valid_stream_name(parts[2]):
        stream, daemon, epoch = parts[2], parts[3], parts[4]
    else:
        return None
    if not _LIFE_RE.fullmatch(daemon) or not epoch.isdigit() or len(epoch) > 20:
        return None
    return stream, daemon, int(epoch)
