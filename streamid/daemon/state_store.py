"""``--state-dir`` persistence: the latest model and populations of every stream.

One JSON document per stream, ``<state-dir>/<stream>.json``::

    {"format": "streamid.daemon-state/1", "stream": ..., "version": 7,
     "signature": {...}, "model_message": {...}, "coea_state": "...", "saved_unix_ns": ...}

``model_message`` is the last message published on ``streamid/<stream>/model``
(the engine's model JSON with version, window and metrics); ``coea_state`` the
engine's final populations (its own JSON text), from which a restarted daemon
resumes warm; ``signature`` (signal names, period, lag bounds...) tells whether
that warm start still fits the stream.

Every write is atomic: the document goes to a temporary file in the same
directory, is flushed and fsync'ed, then ``os.replace``d over the old one (and
the directory fsync'ed), so a crash at any moment leaves either the previous or
the new document, never a half-written one.  Nothing is ever unpickled: the
files are JSON, parsed with :func:`json.loads`.

Nothing the daemon writes here can hang it or be redirected: the version record
is opened non-blocking, without following a symlink, and checked on its
descriptor to be a regular file; a document is only ever renamed over a regular
file.  Whatever else sits at one of these names (a FIFO, a device, a directory,
a symlink) is moved aside as ``<name>.quarantined-<ns>`` (the newest
:data:`KEEP_QUARANTINED` of a name kept; a directory is never deleted) with an
ERROR log, and a fresh regular file is written in its place; if it cannot be
moved, the write fails with an :class:`OSError` (a failed save: the model is
still published, :mod:`streamid.daemon.versions`).
"""

from __future__ import annotations

import errno
import glob
import logging
import os
import stat
import tempfile
import time
from pathlib import Path

from streamid.bounded_files import read_regular_file
from streamid.errors import ConfigError, ModelFormatError
from streamid.online.snapshot import MAX_VERSION, STATE_FORMAT, StreamState
from streamid.wire.keys import STREAM_NAME_RULE, is_valid_stream_name

__all__ = ["KEEP_QUARANTINED", "MAX_STATE_BYTES", "RECORD_COMPACT_BYTES", "RECORD_READ_BYTES", "STATE_FORMAT",
           "StreamState", "StateStore", "atomic_write_text", "open_regular_for_append", "quarantine_odd_file",
           "read_regular_file"]

_log = logging.getLogger(__name__)
_SUFFIX = ".json"
_RECORD = ".versions"
#: Largest state file read (a state with populations is a few MB; the MR damper's ~96 kB).
MAX_STATE_BYTES = 32 * 1024 * 1024
#: A version record longer than this is rewritten to its highest version.
RECORD_COMPACT_BYTES = 4096
#: Bytes of a version record read.
RECORD_READ_BYTES = 64 * 1024
_CORRUPT = ".corrupt-"
_ODD = ".quarantined-"
#: Quarantined files kept per stream (the oldest beyond this are deleted when another is moved aside).
KEEP_QUARANTINED = 8
#: How the version record is opened: never blocks (a FIFO), never follows a symlink, never takes a terminal,
#: not inherited by children.
_APPEND_FLAGS = (os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
                 | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0))
#: What ``os.open`` says of a name that is not a regular file (symlink with O_NOFOLLOW, FIFO without reader, directory).
_ODD_ERRNOS = frozenset({errno.ELOOP, errno.ENXIO, errno.EISDIR, errno.EAGAIN, errno.EWOULDBLOCK, errno.EMLINK})


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "a symlink"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return f"not a regular file (mode {stat.filemode(mode)})"


def quarantine_odd_file(path: Path, kind: str) -> Path:
    """Move ``path`` (something other than a regular file) aside as ``<name>.quarantined-<ns>``, with an ERROR.

    The newest :data:`KEEP_QUARANTINED` of that name are kept (older ones deleted, a directory never).

    Raises
    ------
    OSError
        If it cannot be moved (logged as an ERROR too): the write that needed the name fails.
    """
    q = path.with_name(f"{path.name}{_ODD}{time.time_ns()}")
    try:
        os.rename(path, q)
    except OSError as exc:
        _log.error("state directory: %s is %s, not a regular file, and cannot be moved aside (%s); not written",
                   path, kind, exc)
        raise OSError(f"{path} is {kind}, not a regular file, and cannot be moved aside ({exc})") from exc
    _log.error("state directory: %s was %s, not a regular file; moved aside to %s, a fresh file is written in its "
               "place", path, kind, q.name)
    prefix = path.name + _ODD

    def stamp(p: Path) -> int:
        tail = p.name[len(prefix):]
        return int(tail) if tail.isdigit() else -1

    found = sorted((p for p in path.parent.glob(f"{glob.escape(prefix)}*") if p.name.startswith(prefix)),
                   key=stamp, reverse=True)
    for old in found[KEEP_QUARANTINED:]:
        try:
            if not stat.S_ISDIR(old.lstat().st_mode):
                old.unlink()
        except OSError:
            pass
    return q


def _regular_or_moved_aside(path: Path) -> None:
    """Before a rename over ``path``: something there that is not a regular file is quarantined."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        quarantine_odd_file(path, _kind(mode))


def open_regular_for_append(path: Path) -> int:
    """A descriptor of ``path`` opened for appending (created if missing), checked to be a regular file.

    Opened non-blocking, without following a symlink; checked with ``fstat`` on the descriptor.  A FIFO,
    device, directory or symlink there is quarantined (:func:`quarantine_odd_file`) and a fresh file made.

    Raises
    ------
    OSError
        If no regular file can be opened there.
    """
    for attempt in range(2):
        try:
            fd = os.open(path, _APPEND_FLAGS, 0o644)
        except OSError as exc:
            try:
                mode = os.lstat(path).st_mode
            except OSError:
                raise exc from None
            if exc.errno not in _ODD_ERRNOS or stat.S_ISREG(mode) or attempt:
                raise
            quarantine_odd_file(path, _kind(mode))
            continue
        try:
            mode = os.fstat(fd).st_mode
        except OSError:
            os.close(fd)
            raise
        if stat.S_ISREG(mode):
            return fd
        os.close(fd)
        if attempt:
            break
        quarantine_odd_file(path, _kind(mode))
    raise OSError(f"{path} is not a regular file after it was moved aside (something keeps putting one there)")


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temp file + fsync + os.replace + dir fsync)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        _regular_or_moved_aside(path)  # a FIFO, device, directory or symlink there: quarantined, not clobbered
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(dfd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(dfd)


class StateStore:
    """The per-stream state files of one ``--state-dir``.

    Parameters
    ----------
    directory
        Created if missing.

    Raises
    ------
    ConfigError
        If the directory cannot be created or is not writable.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"--state-dir must be a creatable, writable directory; got {str(directory)!r} ({exc})") from exc
        if not os.access(self.directory, os.W_OK):
            raise ConfigError(f"--state-dir must be a writable directory; got {str(directory)!r}")
        for tmp in self.directory.glob(f".*{_SUFFIX}.*.tmp"):  # left by a writer killed mid-write
            try:
                tmp.unlink()
            except OSError:
                pass

    def path(self, stream: str) -> Path:
        """File of ``stream``."""
        if not is_valid_stream_name(stream):
            raise ConfigError(f"stream name must be {STREAM_NAME_RULE}; got {stream!r}")
        return self.directory / f"{stream}{_SUFFIX}"

    def streams(self) -> list[str]:
        """Streams with a saved state."""
        out = []
        for p in sorted(self.directory.glob(f"*{_SUFFIX}")):
            name = p.name[: -len(_SUFFIX)]
            if is_valid_stream_name(name) and not name.startswith("."):
                out.append(name)
        return out

    def load(self, stream: str) -> StreamState | None:
        """The saved state of ``stream`` (None if there is none).

        Raises
        ------
        ModelFormatError
            If the file exists but is not a valid state document of that stream.
        """
        p = self.path(stream)
        try:
            text = read_regular_file(p, MAX_STATE_BYTES).decode("utf-8")
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ModelFormatError(f"{p}: cannot read the daemon state ({exc})") from exc
        st = StreamState.from_json(text, source=str(p))
        if st.stream != stream:
            raise ModelFormatError(f"{p}: holds the state of stream {st.stream!r}, expected {stream!r}")
        return st

    def save(self, state: StreamState) -> Path:
        """Write ``state`` atomically; returns the file."""
        p = self.path(state.stream)
        atomic_write_text(p, state.to_json())
        return p

    def record_path(self, stream: str) -> Path:
        """The version record of ``stream`` (see the module docstring)."""
        return self.path(stream).with_name(f"{stream}{_RECORD}")

    def record_version(self, stream: str, version: int) -> None:
        """Append ``version`` to the stream's version record (fsync'ed); compact it when it is long.

        Raises
        ------
        OSError
            If it cannot be written (the caller treats it as a failed save).
        """
        p = self.record_path(stream)
        fd = open_regular_for_append(p)  # a FIFO there would block for ever under the stream lock
        try:
            os.write(fd, f"{int(version)}\n".encode())
            os.fsync(fd)
            size = os.fstat(fd).st_size
        finally:
            os.close(fd)
        if size > RECORD_COMPACT_BYTES:
            best = max(self.recorded_version(stream) or 0, int(version))
            atomic_write_text(p, f"{best}\n")

    def recorded_version(self, stream: str) -> int | None:
        """The highest version in the stream's record (None: no record, or no credible line in it).

        Lines that are not an integer in [0, 2**53) are ignored; a record that is not a regular
        file is ignored (a warning is the caller's).
        """
        try:  # a record larger than the bound (it is compacted long before): its head still counts
            raw = read_regular_file(self.record_path(stream), RECORD_READ_BYTES, head=True)
        except (OSError, ValueError):
            return None
        best: int | None = None
        for line in raw.split(b"\n"):
            line = line.strip()
            if line.isdigit() and len(line) <= 19:
                v = int(line)
                if v < MAX_VERSION and (best is None or v > best):
                    best = v
        return best

    def quarantine(self, stream: str) -> Path | None:
        """Move an unreadable state file aside (``.corrupt-<ns>``); returns the new path.

        The newest :data:`KEEP_QUARANTINED` quarantined files of the stream are kept
        (:mod:`streamid.daemon.versions` reads the highest version in them); older
        ones are deleted, so a file damaged at every start cannot fill the directory.
        """
        p = self.path(stream)
        if not p.exists():
            return None
        q = p.with_name(f"{p.name}{_CORRUPT}{time.time_ns()}")
        os.replace(p, q)
        for old in self.quarantined(stream)[KEEP_QUARANTINED:]:
            try:
                old.unlink()
            except OSError:
                pass
        return q

    def quarantined(self, stream: str) -> list[Path]:
        """The stream's quarantined state files, newest first."""
        prefix = self.path(stream).name + _CORRUPT

        def stamp(p: Path) -> int:
            tail = p.name[len(prefix):]
            return int(tail) if tail.isdigit() else -1

        found = [p for p in self.directory.glob(f"{glob.escape(prefix)}*") if p.name.startswith(prefix)]
        return sorted(found, key=stamp, reverse=True)
