"""Who publishes a model: the daemon's identity and the epoch of its current life.

Every model-update document the daemon publishes carries ``"origin":
{"daemon": <id>, "epoch_ns": <unix ns>}``.  ``daemon`` is stable per
``--state-dir`` (a random id kept in ``<state-dir>/daemon.identity``; a daemon
without a state directory draws a new one at every start); ``epoch_ns`` is the
start of this life.  A subscriber that sees an origin with a later epoch knows
the publisher restarted, instead of taking its models for stale ones.

The epoch never goes backwards for one state directory: the file also keeps the
last epoch handed out, and a start whose wall clock is behind it (a clock stepped
back) takes ``last + 1``.  The file is written atomically; if it cannot be written
(a full disk, a read-only directory) the daemon still starts with the identity it
read or drew, says so once, and writes it when a state save succeeds again
(:class:`~streamid.daemon.versions.VersionKeeper`).  A damaged file is replaced by a new identity
(the epoch then comes from the clock alone).

The file is JSON (``json.loads``, never unpickled)::

    {"format": "streamid.daemon-identity/1", "daemon": "5f0c...", "last_epoch_ns": 1764...}
"""

from __future__ import annotations

import json
import logging
import re
import secrets
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from streamid.daemon.state_store import atomic_write_text
from streamid.bounded_files import read_regular_file

__all__ = ["IDENTITY_FILE", "IDENTITY_FORMAT", "Origin", "daemon_origin", "save_identity"]

_log = logging.getLogger(__name__)

#: File name of the identity inside ``--state-dir`` (not ``*.json``: never taken for a stream's state).
IDENTITY_FILE = "daemon.identity"
IDENTITY_FORMAT = "streamid.daemon-identity/1"
#: What a daemon id looks like (the ones drawn here are 16 lowercase hex digits).
_ID_RULE = re.compile(r"[0-9A-Za-z][0-9A-Za-z._-]{0,63}")
#: The identity file is tiny; anything bigger is not one.
_MAX_FILE_BYTES = 4096


@dataclass(frozen=True)
class Origin:
    """The publisher of a model: daemon id and the start of its life (unix ns)."""

    daemon: str
    epoch_ns: int

    def as_dict(self) -> dict[str, Any]:
        """The ``origin`` object of a model-update document."""
        return {"daemon": self.daemon, "epoch_ns": int(self.epoch_ns)}


def _new_id() -> str:
    return secrets.token_hex(8)


def _read(path: Path) -> tuple[str | None, int, str]:
    """(daemon id or None, last epoch or 0, why the file was not usable or '')."""
    try:  # a regular file only (a FIFO would block the start, a device never end)
        raw = read_regular_file(path, _MAX_FILE_BYTES)
    except FileNotFoundError:
        return None, 0, ""
    except OSError as exc:
        return None, 0, f"cannot read {path} ({exc})"
    except ValueError as exc:
        return None, 0, f"{exc}: not an identity file"
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        return None, 0, f"{path} is not JSON ({exc})"
    if not isinstance(doc, dict) or doc.get("format") != IDENTITY_FORMAT:
        return None, 0, f"{path}: expected a document with format {IDENTITY_FORMAT!r}"
    daemon, last = doc.get("daemon"), doc.get("last_epoch_ns", 0)
    if not isinstance(daemon, str) or not _ID_RULE.fullmatch(daemon):
        return None, 0, f"{path}: 'daemon' must be 1-64 letters, digits, '.', '_' or '-'; got {daemon!r}"
    if isinstance(last, bool) or not isinstance(last, int) or last < 0:
        last = 0
    return daemon, last, ""


def daemon_origin(state_dir: str | Path | None, *, now_ns: int | None = None) -> Origin:
    """The origin of this daemon life (reads and updates ``<state_dir>/daemon.identity``).

    Never raises for a file problem: a missing or damaged file gets a new id, a file
    that cannot be written is logged once (``WARNING``) and the life goes on.
    """
    now = time.time_ns() if now_ns is None else int(now_ns)
    if state_dir is None:
        return Origin(_new_id(), now)
    path = Path(state_dir) / IDENTITY_FILE
    for tmp in Path(state_dir).glob(f".{IDENTITY_FILE}.*.tmp"):  # left by a daemon killed mid-write
        try:
            tmp.unlink()
        except OSError:
            pass
    daemon, last, why = _read(path)
    if why:
        _log.warning("daemon identity: %s; starting under a new identity", why)
    if daemon is None:
        daemon = _new_id()
    origin = Origin(daemon, max(now, last + 1))
    error = save_identity(state_dir, origin)
    if error:
        _log.warning("daemon identity not saved to %s (%s); this life's models still carry origin %s, epoch %d",
                     path, error, origin.daemon, origin.epoch_ns)
    return origin


def save_identity(state_dir: str | Path, origin: Origin) -> str:
    """Write ``origin`` as ``<state_dir>/daemon.identity`` atomically; returns the error ('' if written)."""
    doc = {"format": IDENTITY_FORMAT, "daemon": origin.daemon, "last_epoch_ns": int(origin.epoch_ns)}
    try:
        atomic_write_text(Path(state_dir) / IDENTITY_FILE, json.dumps(doc, separators=(",", ":")))
    except OSError as exc:
        return str(exc) or type(exc).__name__
    return ""
