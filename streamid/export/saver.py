"""``streamid watch --save-fmu DIR``: each newly served champion as an FMU, within stated bounds.

A model update comes from whoever publishes on the bus, so everything it makes this process spend is bounded
(docs/security.md, docs/reliability.md):

==========================  ==================  ==========================================================
bound                       default             what happens beyond it
==========================  ==================  ==========================================================
``keep``                    3 per stream        the oldest versioned FMU of the stream is deleted
``max_bytes``               256 MiB             the oldest versioned FMUs (any stream) are deleted; a
                                                stream's newest FMU that still does not fit is not written
``max_pending``             4 models            the oldest pending model is dropped (counted, said)
compile time                from the model's    the compiler's process group is killed; the model is
                            size (30 s at least) skipped (said)
model size                  compiler.MAX_*      refused before any file (said)
==========================  ==================  ==========================================================

File names cannot collide across streams: a stream name is 1-128 characters of ``A-Z a-z 0-9 _ - .``, so the
newest FMU of a stream is ``DIR/<stream>.fmu`` and its versions ``DIR/<stream>+v<version>.fmu`` (``+`` is never
in a stream name). Compiles run one at a time on the caller's thread (:meth:`FmuSaver.save_pending`), each
stopped, its process group killed, as soon as ``halted()`` turns true. A model that cannot be exported (names
breaking the one rule for names, numbers C cannot spell, too large, a compile failure) is said on standard error
and skipped: nothing in an update ends the watch.
"""

from __future__ import annotations

import collections
import os
import re
import shutil
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from streamid.errors import ConfigError
from streamid.wire.names import printable

__all__ = ["FmuSaver", "SaveBounds", "newest_name", "version_name"]


@dataclass(frozen=True)
class SaveBounds:
    """What ``--save-fmu`` may spend: FMUs kept per stream, bytes in the folder, models waiting to be compiled."""

    keep: int = 3
    max_bytes: int = 256 * 2**20
    max_pending: int = 4

    def __post_init__(self) -> None:
        if self.keep < 0:
            raise ConfigError(f"--keep must be an integer >= 0 (versioned FMUs kept per stream); got {self.keep}")
        if self.max_bytes < 1:
            raise ConfigError(f"--max-bytes must be an integer >= 1; got {self.max_bytes}")
        if self.max_pending < 1:
            raise ConfigError(f"--max-pending must be an integer >= 1; got {self.max_pending}")


def newest_name(stream: str) -> str:
    """The newest FMU of ``stream``: ``<stream>.fmu``."""
    return f"{stream}.fmu"


def version_name(stream: str, version: int) -> str:
    """Version ``version`` of ``stream``: ``<stream>+v<version>.fmu`` (``+`` is never in a stream name)."""
    return f"{stream}+v{version}.fmu"


def _say(text: str) -> None:
    import sys

    print(printable(text, 1000), file=sys.stderr, flush=True)


class FmuSaver:
    """Writes each offered champion as ``<stream>+v<version>.fmu`` and ``<stream>.fmu`` (see the module docstring).

    An FMU holds the stream's current model of every output (model identifier: the stream's name as a C
    identifier, the same in every version, so a rig's reference to it stays valid). :meth:`offer` is called on
    the subscriber's thread and only queues; :meth:`save_pending` compiles, one model at a time.
    """

    def __init__(self, directory: str, bounds: SaveBounds = SaveBounds(), *,
                 halted: Callable[[], bool] = lambda: False, say: Callable[[str], None] = _say) -> None:
        from streamid.export.compiler import find_compiler

        self.dir = Path(directory)
        if not self.dir.is_dir():
            raise ConfigError(f"--save-fmu needs an existing folder; got {directory!r}")
        find_compiler()  # no compiler: say what to install now, not at the first model
        self.bounds = bounds
        self._halted = halted
        self._say = say
        self._lock = threading.Lock()
        self._current: dict[str, dict[str, Any]] = {}  # stream -> output -> newest accepted update
        self._pending: collections.deque[tuple[Any, list[Any]]] = collections.deque()
        self.saved = 0
        self.dropped = 0  # pending models dropped for newer ones (max_pending)
        self.failed = 0  # models that could not be exported
        self.deleted = 0  # FMUs deleted by keep / max_bytes

    @property
    def pending(self) -> int:
        """Models waiting to be compiled."""
        with self._lock:
            return len(self._pending)

    def offer(self, up: Any) -> None:
        """Queue ``up`` (an accepted model update); beyond ``max_pending`` the oldest pending one is dropped."""
        with self._lock:
            outputs = self._current.setdefault(up.stream, {})
            outputs[up.output] = up
            self._pending.append((up, [o.model for _, o in sorted(outputs.items())]))
            old = self._pending.popleft() if len(self._pending) > self.bounds.max_pending else None
            if old is not None:
                self.dropped += 1
        if old is not None:
            self._say(f"streamid watch: {old[0].stream} v{old[0].version} not saved as an FMU: dropped for newer models "
                      f"(at most {self.bounds.max_pending} wait to be compiled; {self.dropped} dropped so far)")

    def save_pending(self) -> None:
        """Compile the pending models one at a time, oldest first, until none is left or ``halted()``."""
        while not self._halted():
            with self._lock:
                if not self._pending:
                    return
                up, models = self._pending.popleft()
            self._save(up, models)

    def _save(self, up: Any, models: list[Any]) -> None:
        from streamid.errors import StreamidError
        from streamid.export import c_identifier, write_fmu

        period = up.window.get("period_ns")
        period_s = period / 1e9 if isinstance(period, int) and not isinstance(period, bool) and period > 0 else None
        path = self.dir / version_name(up.stream, up.version)
        newest = self.dir / newest_name(up.stream)
        try:
            write_fmu(models, path, name=c_identifier(up.stream), period_s=period_s, cancelled=self._halted)
            size = path.stat().st_size
            old = newest.stat().st_size if newest.is_file() else 0
            if not self._make_room(up.stream, path, size - old):
                path.unlink()
                raise ConfigError(f"the folder's FMUs would hold more than --max-bytes {self.bounds.max_bytes} bytes "
                                  "with only each stream's newest FMU left: raise --max-bytes or watch fewer streams")
            tmp = self.dir / f".{newest.name}.{os.getpid()}.tmp"
            shutil.copyfile(path, tmp)
            os.replace(tmp, newest)
            if self.bounds.keep == 0:
                self._delete(path)
        except Exception as exc:  # noqa: BLE001 - nothing in one update ends the watch (StreamidError, OSError, ...)
            self.failed += 1
            what = str(exc) if isinstance(exc, (StreamidError, OSError)) else f"{type(exc).__name__}: {exc}"
            self._say(f"streamid watch: {up.stream} v{up.version} not saved as an FMU: {what}")
            return
        self.saved += 1
        self._say(f"streamid watch: {up.stream} v{up.version} saved as "
                  + (f"{path} and {newest}" if self.bounds.keep else f"{newest}"))

    # ---------------------------------------------------------------- the bounds on disk
    def _versions(self, stream: str | None) -> list[tuple[int, Path]]:
        """``(mtime_ns, path)`` of the versioned FMUs in the folder (of ``stream``; None: of every stream)."""
        pat = re.compile((re.escape(stream) if stream is not None else r"[A-Za-z0-9_.\-]{1,128}") + r"\+v[0-9]+\.fmu")
        found = []
        with os.scandir(self.dir) as it:
            for e in it:
                if pat.fullmatch(e.name) and e.is_file(follow_symlinks=False):
                    found.append((e.stat(follow_symlinks=False).st_mtime_ns, Path(e.path)))
        return sorted(found)

    def _total_bytes(self) -> int:
        """Bytes of every FMU this saver's naming makes in the folder (versioned and newest)."""
        total = 0
        with os.scandir(self.dir) as it:
            for e in it:
                if e.name.endswith(".fmu") and not e.name.startswith(".") and e.is_file(follow_symlinks=False):
                    total += e.stat(follow_symlinks=False).st_size
        return total

    def _delete(self, path: Path) -> None:
        try:
            path.unlink()
            self.deleted += 1
        except OSError as exc:
            self._say(f"streamid watch: cannot delete {path}: {exc}")

    def _make_room(self, stream: str, written: Path, grows: int) -> bool:
        """Delete ``stream``'s versions beyond ``keep`` (``written``, the newest, counts as one), then the oldest
        versions of any stream until the folder's FMUs, with the newest copy of ``written`` (``grows`` bytes more),
        fit ``max_bytes``; False if they cannot (only newest FMUs left)."""
        versions = self._versions(None)
        kept = written.stat().st_size if self.bounds.keep > 0 else 0
        floor = self._total_bytes() - sum(p.stat().st_size for _, p in versions) + kept + grows
        if floor > self.bounds.max_bytes:  # even with every other version deleted: delete none
            return False
        mine = [p for _, p in self._versions(stream) if p != written]
        for p in mine[: max(0, len(mine) - max(0, self.bounds.keep - 1))]:
            self._delete(p)
        total = self._total_bytes() + grows - (written.stat().st_size if self.bounds.keep == 0 else 0)
        for _, p in self._versions(None):
            if total <= self.bounds.max_bytes:
                break
            if p != written:
                size = p.stat().st_size
                self._delete(p)
                total -= size
        return total <= self.bounds.max_bytes
