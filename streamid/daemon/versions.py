"""Versions a subscriber can trust: never reused after lost or damaged state, nor after a full disk.

A subscriber keeps, per stream, the newest model it has seen and skips anything
older; so a daemon that numbered from 1 again after losing its state would go
unheard.  :class:`VersionKeeper` is what the daemon does about it:

* **Origin.**  Every :class:`~streamid.online.OnlineIdentifier` the daemon
  creates gets this life's :class:`~streamid.daemon.identity.Origin` (daemon id,
  epoch): a restart is recognised as one rather than ignored.
* **Damaged state.**  :meth:`VersionKeeper.resume` loads the stream's saved state;
  an unreadable file is quarantined (``<stream>.json.corrupt-<ns>``) and the
  highest version still readable in the quarantined files is found by a plain
  scan of their bytes for ``"version": <digits>`` (valid JSON or not:
  :func:`highest_version_in`).  The next version is above it.
* **Version record.**  :meth:`VersionKeeper.persist` appends each version to
  ``<stream>.versions`` before the state carrying it is saved, and :meth:`VersionKeeper.resume`
  numbers above the record's highest version: a state file emptied, deleted or replaced by
  an older one never makes a version number be used twice.
* **No state.**  Before the first model of a stream that had no usable state,
  :meth:`VersionKeeper.settle` asks the network for that stream's current model
  (``streamid/<stream>/model``, bounded by ``query_timeout_s``, 1 s by default)
  and numbers above the highest version answered (if a still-running old life, a
  replica or a storage answers).  Only replies on the stream's own key, naming
  that stream, are counted, and only versions at most :data:`MAX_VERSION_STEP`
  above what this daemon knows already (its version record, quarantined states,
  this life's memory; 0 when it knows nothing): a replayed or forged answer of
  2**53 - 1 does not move the numbering (a WARNING names it), it can push it up by
  at most the step per daemon life.  The rule is the same with the shipped access
  control (only the ``daemon`` user can answer there).  A genuine predecessor more
  than the step ahead (a state directory lost after a million models) is not
  followed either: this life numbers from its own floor under its later epoch,
  which every subscriber takes as a restart.
* **Full disk.**  The rule is *keep publishing*: an update whose state cannot be
  saved is still published (the identifier marks it ``saved = False`` and its
  status ``state_saved: false`` with the error).  Versions stay unique within the
  life because they are numbered in memory (also when a released stream's slot is
  served again: :meth:`VersionKeeper.persist` remembers the unsaved version); a
  later life is told apart by its origin (later epoch).  If the daemon dies before
  a save succeeds again, the next life resumes from the last saved version and may
  number again versions the dead life published after it, under another origin:
  (origin, version) is unique, the version alone is not.  :meth:`VersionKeeper.persist`
  logs one warning per stream when saving starts failing and one line when it
  works again, never one per update.

Bounds (a remote party or a damaged disk can make us spend no more than this):
each quarantined file is scanned up to :data:`SCAN_MAX_BYTES`, at most
:data:`~streamid.daemon.state_store.KEEP_QUARANTINED` files per stream; one
network query per stream and daemon life, at most ``query_timeout_s``, at most
:data:`MAX_REPLIES` replies of at most :data:`MAX_REPLY_BYTES` each and
:data:`MAX_QUERY_BYTES` together read (the rest measured and dropped unread, counted
in the log), a version taken from it at most :data:`MAX_VERSION_STEP` above the daemon's own; a
version at or above :data:`MAX_VERSION` (2**53, the largest integer every JSON reader
keeps exactly) is ignored as not credible (a state file holding one is refused and quarantined);
only regular files are scanned.
"""

from __future__ import annotations

import logging
import re
import threading
from dataclasses import dataclass
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any, Protocol

from streamid.daemon.identity import IDENTITY_FILE, Origin, save_identity
from streamid.daemon.state_store import StateStore, read_regular_file
from streamid.errors import ModelFormatError, StreamidError
from streamid.online.snapshot import StreamState
from streamid.wire.documents import MAX_DOCUMENT_BYTES, MAX_VERSION, parse_model_update_fields
from streamid.wire.keys import model_key

__all__ = ["MAX_QUERY_BYTES", "MAX_REPLIES", "MAX_REPLY_BYTES", "MAX_UNSAVED", "MAX_VERSION", "MAX_VERSION_STEP",
           "within_step",
           "SCAN_MAX_BYTES", "NetworkVersions", "VersionKeeper", "highest_version_in", "highest_version_on_network",
           "network_versions"]

_log = logging.getLogger(__name__)

#: Bytes of one quarantined file scanned for versions (state files with populations are a few MB).
SCAN_MAX_BYTES = 64 * 1024 * 1024
#: Replies of the network query that are read, the size of each (the wire format's bound of a document) and of all.
MAX_REPLIES = 64
MAX_REPLY_BYTES = MAX_DOCUMENT_BYTES
MAX_QUERY_BYTES = 64 * 1024 * 1024
#: How far above what the daemon knows a version answered by the network may raise its numbering (one daemon life):
#: 10^6 versions, 11.6 days of one model a second.  2**53 / 10**6: nine billion lives to poison the bound.
MAX_VERSION_STEP = 1_000_000


def within_step(version: int, known: int) -> bool:
    """Whether a version learned from the bus (a reply to the version query, a state handed over by a sharing
    daemon) may move this daemon's: at most :data:`MAX_VERSION_STEP` above the highest it knows."""
    return version <= known + MAX_VERSION_STEP
#: Streams whose unsaved version is remembered in memory (one small tuple each; the oldest is forgotten first).
MAX_UNSAVED = 100_000
_VERSION_RE = re.compile(rb'"version"\s*:\s*(\d{1,19})(?![\d.eE])')


class _Ident(Protocol):  # what is used of an OnlineIdentifier (typing only)
    stream: str

    @property
    def version(self) -> int: ...

    def restore(self, state: StreamState) -> list[str]: ...

    def raise_version_floor(self, version: int) -> None: ...


class _Querier(Protocol):  # what is used of a Bus (typing only)
    def get(self, key_expr: str, timeout_s: float = 1.0, *, all_replies: bool = False, max_replies: int = ...,
            max_bytes: int = ..., max_reply_bytes: int | None = None) -> list[tuple[str, bytes]]: ...


def highest_version_in(path: str | Path, max_bytes: int = SCAN_MAX_BYTES) -> int | None:
    """The highest ``"version": N`` in the first ``max_bytes`` of a file, JSON or not (None: none, unreadable).

    A damaged state document (cut short, bytes flipped, not JSON any more) usually still
    holds its ``"version"`` fields; that is all this reads.  Versions above
    :data:`MAX_VERSION` are ignored; a file that is not a regular file is not read.
    """
    try:
        raw = read_regular_file(path, max_bytes, head=True)
    except (OSError, ValueError):
        return None
    best: int | None = None
    for m in _VERSION_RE.finditer(raw):
        v = int(m.group(1))
        if v < MAX_VERSION and (best is None or v > best):
            best = v
    return best


@dataclass(frozen=True)
class NetworkVersions:
    """What the network answered to a version query: the credible versions of the stream, what was dropped unread."""

    versions: tuple[int, ...] = ()
    dropped: int = 0
    dropped_bytes: int = 0


def network_versions(bus: _Querier, stream: str, timeout_s: float) -> NetworkVersions:
    """The versions of ``stream`` the network answers on its model key within ``timeout_s`` (sorted, distinct).

    At most :data:`MAX_REPLIES` replies of at most :data:`MAX_REPLY_BYTES` each and :data:`MAX_QUERY_BYTES`
    together are read; only a document of that stream, on its own key, with a version in [0, 2**53), counts.
    """
    key = model_key(stream)
    found: set[int] = set()
    # every reply (Zenoh would keep one per key): a bad one must not hide a good one
    replies = bus.get(key, timeout_s=timeout_s, all_replies=True, max_replies=MAX_REPLIES, max_bytes=MAX_QUERY_BYTES,
                      max_reply_bytes=MAX_REPLY_BYTES)
    for reply_key, payload in replies:
        if reply_key != key or len(payload) > MAX_REPLY_BYTES:
            continue
        try:
            fields = parse_model_update_fields(payload)
        except (ModelFormatError, ValueError):
            continue
        v = fields.get("version")
        if fields.get("stream") != stream or not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < MAX_VERSION:
            continue
        found.add(v)
    return NetworkVersions(tuple(sorted(found)), int(getattr(replies, "dropped", 0)),
                           int(getattr(replies, "dropped_bytes", 0)))


def highest_version_on_network(bus: _Querier, stream: str, timeout_s: float) -> int | None:
    """The highest version of ``stream`` the network answers on its model key within ``timeout_s`` (no step bound)."""
    got = network_versions(bus, stream, timeout_s).versions
    return got[-1] if got else None


class VersionKeeper:
    """The daemon's guard of its version numbers (see the module docstring).

    Parameters
    ----------
    store
        The ``--state-dir`` (None: nothing saved; every stream starts without state).
    origin
        This daemon life's origin.
    query_timeout_s
        Bound of the network query before a stateless stream's first model.
    """

    def __init__(self, store: StateStore | None, origin: Origin, *, query_timeout_s: float = 1.0) -> None:
        if not query_timeout_s > 0:
            raise ValueError(f"query_timeout_s must be > 0 seconds; got {query_timeout_s!r}")
        self.store = store
        self.origin = origin
        self.query_timeout_s = float(query_timeout_s)
        self._lock = threading.Lock()
        #: streams without usable state whose network query is still to do -> the highest version known here
        self._to_ask: dict[str, int] = {}
        #: stream -> (error of its failing saves, highest version not saved); warned once per stream
        self._unsaved: dict[str, tuple[str, int]] = {}

    @property
    def origin_doc(self) -> dict[str, Any]:
        """``origin`` as passed to :class:`~streamid.online.OnlineIdentifier`."""
        return self.origin.as_dict()

    def resume(self, ident: _Ident) -> StreamState | None:
        """Restore ``ident`` from the store; on damage quarantine and recover the version; returns the state used."""
        name = ident.stream
        saved: StreamState | None = None
        floor: int | None = None
        if self.store is not None:
            try:
                saved = self.store.load(name)
            except ModelFormatError as exc:
                moved = self.store.quarantine(name)
                _log.error("stream %s: unreadable state (%s); moved to %s, starting cold", name, exc, moved)
            if saved is not None:
                for warning in ident.restore(saved):
                    _log.warning("stream %s: %s", name, warning)
                _log.info("stream %s: resumed at version %d from %s", name, saved.version, self.store.path(name))
            floor, where = self._quarantined_floor(name)
            recorded = self.store.recorded_version(name)
            if recorded is not None and (floor is None or recorded > floor):
                floor, where = recorded, str(self.store.record_path(name))
            with self._lock:
                unsaved = self._unsaved.get(name)
            if unsaved is not None and (floor is None or unsaved[1] > floor):
                floor, where = unsaved[1], "this daemon life's memory (its state could not be saved)"
            if floor is not None and floor > ident.version:
                ident.raise_version_floor(floor)
                _log.warning("stream %s: versions continue above v%d, the highest found in %s", name, floor, where)
        if saved is None:
            with self._lock:
                self._to_ask[name] = max(ident.version, floor or 0)
        return saved

    def _quarantined_floor(self, name: str) -> tuple[int | None, str]:
        assert self.store is not None
        best: int | None = None
        where = ""
        for path in self.store.quarantined(name):
            v = highest_version_in(path)
            if v is not None and (best is None or v > best):
                best, where = v, str(path)
        return best, where

    def settled(self, name: str) -> None:
        """The stream's version is known from elsewhere (a state handed over by its previous owner): no query."""
        with self._lock:
            self._to_ask.pop(name, None)

    def needs_settle(self, name: str) -> bool:
        """Whether :meth:`settle` still has a network query to do for this stream."""
        with self._lock:
            return name in self._to_ask

    def settle(self, ident: _Ident, bus: _Querier | None, lock: AbstractContextManager[Any] | None = None) -> int | None:
        """Once per stream without usable state, before its first model: ask the network, raise the floor.

        Call it without holding the stream's lock (the query waits up to ``query_timeout_s``);
        ``lock`` is taken to raise the floor.  Returns the highest version answered within
        :data:`MAX_VERSION_STEP` of the daemon's own (None: none, or nothing to do).  A transport error is logged and ends the attempt (the origin's
        epoch still tells the restart).
        """
        name = ident.stream
        with self._lock:
            if name not in self._to_ask:
                return None
            known_here = self._to_ask.pop(name)
        if bus is None:
            return None
        try:
            got = network_versions(bus, name, self.query_timeout_s)
        except StreamidError as exc:
            _log.warning("stream %s: could not ask the network for its current version (%s)", name, exc)
            return None
        if got.dropped:
            _log.warning("stream %s: %d replies (%d bytes) to the version query dropped unread beyond its bound "
                         "(%d replies, %d bytes)", name, got.dropped, got.dropped_bytes, MAX_REPLIES, MAX_QUERY_BYTES)
        if not got.versions:
            return None
        with lock if lock is not None else nullcontext():
            known = max(ident.version, known_here)
            within = [v for v in got.versions if within_step(v, known)]
            floor = within[-1] if within else None
            raise_it = floor is not None and floor > known
            if raise_it:
                assert floor is not None
                ident.raise_version_floor(floor)
        beyond = [v for v in got.versions if not within_step(v, known)]
        if beyond:
            _log.warning("stream %s: the network answered v%d, more than %d (MAX_VERSION_STEP) above v%d, the highest "
                         "version this daemon knows: not taken (a replayed or forged answer, or a predecessor whose "
                         "state was lost long ago); versions continue above v%d under this life's origin %s epoch %d",
                         name, beyond[-1], MAX_VERSION_STEP, known, floor if raise_it else known,
                         self.origin.daemon, self.origin.epoch_ns)
        if raise_it:
            _log.warning("stream %s: no saved state, but the network serves v%d: versions continue above it",
                         name, floor)
        return floor

    def persist(self, state: StreamState) -> None:
        """Save ``state`` in the store (the identifier's ``persist``); re-raises a failure after noting it.

        The first failure of a stream logs one warning (the rule: models are still published),
        the first success after failures one line; the version of a state that could not be
        saved is remembered for this daemon life (at most :data:`MAX_UNSAVED` streams), so a
        stream whose slot is released and served again resumes above it.
        """
        if self.store is None:
            return
        name = state.stream
        try:
            self.store.record_version(name, state.version)  # first: a state older than the record is never trusted
            self.store.save(state)
        except (OSError, ValueError) as exc:
            error = str(exc)[:300] or type(exc).__name__
            with self._lock:
                first = name not in self._unsaved
                if first and len(self._unsaved) >= MAX_UNSAVED:
                    self._unsaved.pop(next(iter(self._unsaved)))
                prev = self._unsaved.get(name, ("", 0))[1]
                self._unsaved[name] = (error, max(prev, state.version))
            if first:
                _log.warning("stream %s: state not saved (%s); models are still published, their versions kept "
                             "unique in memory and by origin %s epoch %d; the status says state_saved: false until "
                             "a save succeeds (not repeated)", name, error, self.origin.daemon, self.origin.epoch_ns)
            raise
        with self._lock:
            was = self._unsaved.pop(name, None)
        if was is not None:
            _log.warning("stream %s: state saved again (v%d; the saves had failed with: %s)", name, state.version, was[0])
            if not (self.store.directory / IDENTITY_FILE).exists():  # it could not be written at start either
                save_identity(self.store.directory, self.origin)

    def unsaved(self) -> dict[str, str]:
        """Streams whose newest state could not be saved, with the error."""
        with self._lock:
            return {k: v[0] for k, v in self._unsaved.items()}
