"""The ``.rrd`` files of the diagnostics: segment names, rotation, disk bounds, checks and repair.

No ``rerun`` import here (:mod:`streamid.viz.rerun_view` is the only module that
imports it); the repair runs the ``rerun`` command of rerun-sdk.

Segments
    A recording written to ``FILE.rrd`` is continued in ``FILE.001.rrd``,
    ``FILE.002.rrd``... (the number grows past 999 as needed).  Every segment is a
    whole recording file of the same recording id: ``rerun FILE.rrd FILE.0*.rrd``
    and ``streamid view FILE.rrd`` show them as one recording.  The oldest
    segments are removed (and counted) past ``keep`` segments or ``max_mb`` in
    all, so ``FILE.rrd`` itself may be gone on a long run.
Why rotate by time
    A file sink writes the footer (the index that ``rerun rrd verify`` checks)
    only when it is closed.  A SIGKILL leaves the open segment without one:
    ``rerun rrd verify`` fails on it with "Missing RRD footer", though its complete
    chunks are readable.  Closing the segment every ``rotate_s`` seconds (once
    something was drawn into it; an idle writer closes it on a timer) leaves every
    older segment whole; :func:`repair` writes a verified copy of the open one.
    Switching segments keeps the same recording stream (a new file sink), ~10 ms
    with the series styles and the layout sent again.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from streamid.errors import ConfigError

__all__ = [
    "RRD_FORM",
    "Segments",
    "RepairReport",
    "segment_path",
    "segments_of",
    "check_rrd",
    "has_footer",
    "resolve",
    "verify",
    "repair",
]

#: What a user may pass where an .rrd is expected (for error messages).
RRD_FORM = "a Rerun recording FILE.rrd (as written by `streamid daemon --rrd FILE.rrd` or the rerun SDK)"
_MAGIC = b"RRF"  # every .rrd starts with RRF0/RRF1/RRF2
_FOOTER = b"RRF2FOOT"  # ... and a closed one ends with RRF2FOOT + a 4-byte version
_VERIFIED = "1 file verified without error"


def segment_path(base: str | os.PathLike[str], index: int) -> Path:
    """Segment ``index`` of the recording ``base``: ``base`` itself for 0, else ``<stem>.<index:03d>.rrd``."""
    p = Path(base)
    if index == 0:
        return p
    return p.with_name(f"{p.stem}.{index:03d}{p.suffix or '.rrd'}")


def _index_of(base: Path, candidate: Path) -> int | None:
    if candidate == base:
        return 0
    m = re.fullmatch(re.escape(base.stem) + r"\.(\d{3,})" + re.escape(base.suffix or ".rrd"), candidate.name)
    return int(m.group(1)) if m else None


def segments_of(base: str | os.PathLike[str]) -> list[Path]:
    """The segments of ``base`` that exist (``base`` and ``<stem>.NNN.rrd``), in the order they were written."""
    p = Path(base)
    found: list[tuple[int, Path]] = []
    try:
        names = os.listdir(p.parent if str(p.parent) else ".")
    except OSError:
        return []
    for name in names:
        cand = p.with_name(name)
        idx = _index_of(p, cand)
        if idx is not None and cand.is_file():
            found.append((idx, cand))
    return [c for _, c in sorted(found)]


def check_rrd(path: str | os.PathLike[str]) -> Path:
    """``path`` if it is a readable .rrd file, else a :class:`ConfigError` naming it and the accepted form."""
    p = Path(path)
    if p.suffix != ".rrd":
        raise ConfigError(f"{str(p)!r} is not an .rrd file (its name must end in .rrd); give {RRD_FORM}")
    if not p.exists():
        raise ConfigError(f"no file {str(p)!r}; give {RRD_FORM}")
    if not p.is_file():
        raise ConfigError(f"{str(p)!r} is not a file; give {RRD_FORM}")
    try:
        with open(p, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise ConfigError(f"{str(p)!r} cannot be read ({exc.strerror}); give {RRD_FORM}") from exc
    if not head.startswith(_MAGIC):
        raise ConfigError(f"{str(p)!r} is not a Rerun recording: it does not start with RRF "
                          f"(it starts with {head!r}); give {RRD_FORM}")
    return p


def has_footer(path: str | os.PathLike[str]) -> bool:
    """Whether the .rrd at ``path`` ends with a footer (it was closed; a SIGKILLed writer leaves none)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            if size < len(_FOOTER) + 4:
                return False
            fh.seek(size - len(_FOOTER) - 4)
            return fh.read(len(_FOOTER)) == _FOOTER
    except OSError:
        return False


def resolve(paths: Iterable[str | os.PathLike[str]]) -> tuple[list[Path], list[Path]]:
    """The files to show for ``paths``: each .rrd with its continuation segments, checked, without repeats.

    A name whose own file was removed by rotation still resolves to its segments.  Returns the
    files and the continuation segments left out because they are empty (their writer was
    killed as it created them).  Raises :class:`ConfigError` naming the first path that is not
    an .rrd or has no file at all.
    """
    out: dict[Path, None] = {}
    empty: list[Path] = []
    for given in paths:
        p = Path(given)
        if p.suffix != ".rrd":
            raise ConfigError(f"{str(p)!r} is not an .rrd file (its name must end in .rrd); give {RRD_FORM}")
        segs = segments_of(p)
        if not segs:
            check_rrd(p)  # raises: nothing there (names the file)
        for s in segs or [p]:
            if s != p and s.stat().st_size < len(_MAGIC) + 1:
                empty.append(s)
                continue
            out[check_rrd(s)] = None
    return list(out), empty


def verify(path: str | os.PathLike[str], *, rerun: str, timeout_s: float = 120.0) -> tuple[bool, str]:
    """``rerun rrd verify PATH``: (passed, what it said).  Its exit code alone is not enough (a garbage file gives 0)."""
    res = subprocess.run([rerun, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=timeout_s)
    said = (res.stdout + res.stderr).strip()
    return res.returncode == 0 and _VERIFIED in said, said


@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair` did."""

    source: Path
    output: Path
    source_had_footer: bool
    source_bytes: int
    output_bytes: int
    chunks: int  # data chunks in the verified copy (every complete chunk the source held)

    def __str__(self) -> str:
        state = "had a footer" if self.source_had_footer else "had no footer"
        return (f"{self.source} ({self.source_bytes} bytes, {state}): {self.chunks} chunks recovered into "
                f"{self.output} ({self.output_bytes} bytes, verified by `rerun rrd verify`)")


def repair(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    *,
    rerun: str,
    count_chunks: Callable[[Path], int],
    timeout_s: float = 300.0,
) -> RepairReport:
    """Write a verified copy of ``src`` that holds every complete chunk it has (a SIGKILLed segment, say).

    ``rerun rrd merge --continue-on-error`` reads the readable chunks (stopping at
    a half-written one) and writes them with a footer; ``rerun rrd verify`` must
    pass on the result before it is moved to ``out`` (default ``<stem>.repaired.rrd``
    beside ``src``).  ``count_chunks(path)`` counts the data chunks of a verified
    file (:func:`streamid.viz.rerun_view.repair_rrd` passes the SDK's reader).

    Raises
    ------
    ConfigError
        ``src`` is not an .rrd file, ``out`` is ``src`` or not an .rrd name, or no
        complete chunk could be read from ``src`` (nothing to recover).
    RuntimeError
        The ``rerun`` command failed or did not finish within ``timeout_s``.
    """
    source = check_rrd(src)
    dest = Path(out) if out is not None else source.with_name(f"{source.stem}.repaired.rrd")
    if dest.suffix != ".rrd":
        raise ConfigError(f"the repaired copy must be an .rrd file; got -o {str(dest)!r}")
    if dest.resolve() == source.resolve():
        raise ConfigError(f"-o {str(dest)!r} is the damaged file itself; give another FILE.rrd for the copy")
    tmp = dest.with_name(f"{dest.stem}.part-{os.getpid()}-{time.monotonic_ns()}.rrd")
    try:
        try:
            res = subprocess.run([rerun, "rrd", "merge", "--continue-on-error", str(source), "-o", str(tmp)],
                                 capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired as exc:
            raise RuntimeError(f"`rerun rrd merge` did not finish repairing {source} within {timeout_s:.0f} s") from exc
        if res.returncode != 0 or not tmp.is_file():
            tail = " | ".join(res.stderr.strip().splitlines()[-3:])
            raise RuntimeError(f"`rerun rrd merge` could not read {source} (exit {res.returncode}): {tail}")
        ok, said = verify(tmp, rerun=rerun, timeout_s=timeout_s)
        chunks = count_chunks(tmp) if ok else 0
        if chunks == 0:
            why = next((ln for ln in said.splitlines() if ln.strip() and "Verification failed" not in ln), said)
            raise ConfigError(f"no complete chunk could be read from {str(source)!r} ({source.stat().st_size} bytes): "
                              f"nothing to recover" + ("" if ok else f" (the copy of its readable part: {why})"))
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)
    return RepairReport(source, dest, has_footer(source), source.stat().st_size, dest.stat().st_size, chunks)


class Segments:
    """When to close the open segment and start the next, and which old ones to remove (not thread-safe).

    Parameters
    ----------
    base
        The recording's first file (``FILE.rrd``).
    rotate_mb, rotate_s
        Close the open segment once it passes this size, or once it is this old
        and something was written to it (None: no such limit; both None: one file).
    keep, max_mb
        Keep at most this many segments, and at most this many MB in all
        (counting the open one); the oldest closed ones go first, the open one never.
    """

    def __init__(self, base: str | os.PathLike[str], *, rotate_mb: float | None, rotate_s: float | None,
                 keep: int, max_mb: float | None) -> None:
        self.base = Path(base)
        self.rotate_mb, self.rotate_s, self.keep, self.max_mb = rotate_mb, rotate_s, keep, max_mb
        self.kept: list[Path] = [self.base]  # oldest first; the last one is open
        self._sizes: dict[Path, int] = {}  # closed segments' sizes
        self.index = 0
        self.opened_s = time.monotonic()
        self.dirty = False  # something was written since the open segment was opened
        self.rotations = 0
        self.removed = 0
        self.removed_bytes = 0

    @property
    def open_path(self) -> Path:
        return self.kept[-1]

    def stale(self) -> list[Path]:
        """Continuation segments of ``base`` left by an earlier run (``base`` itself is overwritten)."""
        return [p for p in segments_of(self.base) if p != self.base]

    def due(self, now_s: float | None = None) -> bool:
        """Whether the open segment should be closed now."""
        if self.rotate_mb is None and self.rotate_s is None:
            return False
        if self.rotate_s is not None and self.dirty:
            if (time.monotonic() if now_s is None else now_s) - self.opened_s >= self.rotate_s:
                return True
        if self.rotate_mb is not None:
            try:
                return os.path.getsize(self.open_path) >= self.rotate_mb * 1e6
            except OSError:
                return False
        return False

    def next_path(self) -> Path:
        return segment_path(self.base, self.index + 1)

    def rotated(self, new: Path) -> list[Path]:
        """Record that the open segment was closed and ``new`` opened; removes old segments past the bounds.

        Returns the removed paths (already deleted).
        """
        old = self.open_path
        try:
            self._sizes[old] = os.path.getsize(old)
        except OSError:
            self._sizes[old] = 0
        self.index += 1
        self.rotations += 1
        self.kept.append(new)
        self.opened_s = time.monotonic()
        self.dirty = False
        return self._prune()

    def total_bytes(self) -> int:
        try:
            open_b = os.path.getsize(self.open_path)
        except OSError:
            open_b = 0
        return sum(self._sizes.get(p, 0) for p in self.kept[:-1]) + open_b

    def _prune(self) -> list[Path]:
        gone: list[Path] = []
        total = self.total_bytes()
        while len(self.kept) > 1 and (
            len(self.kept) > self.keep or (self.max_mb is not None and total > self.max_mb * 1e6)
        ):
            p = self.kept.pop(0)
            size = self._sizes.pop(p, 0)
            total -= size
            try:
                os.unlink(p)
            except OSError:
                pass
            self.removed += 1
            self.removed_bytes += size
            gone.append(p)
        return gone

    def stats(self) -> dict[str, int]:
        """Counters: segments kept, their bytes, rotations so far, segments and bytes removed."""
        return {"segments": len(self.kept), "bytes": self.total_bytes(), "rotations": self.rotations,
                "removed": self.removed, "removed_bytes": self.removed_bytes}
