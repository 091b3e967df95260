"""Where the diagnostics go: the ``.rrd`` segments, a served endpoint and a viewer link (no ``rerun`` import here).

:class:`Sinks` keeps one link per sink -- an object with a recording stream
``rec`` (``flush(timeout_sec=...)``, ``disconnect()``), its ``kind`` (``file``,
``serve`` or ``live``), ``path`` and ``reopen(path)`` (a file link goes on in
another file, the previous one closed with its footer) -- made by the ``open_link`` that
:class:`streamid.viz.rerun_view.Viz` hands in, so that only that module imports rerun.
It rotates the file (:class:`streamid.viz.rrd_files.Segments`), probes the viewer
before linking to it, and closes everything on shutdown.  The SDK's gRPC client
buffers without bound while it cannot reach a viewer, so the connection is
probed with a plain TCP connect first: a viewer that is absent or goes away is
reported once (a warning) and the live link is dropped -- identification and the
file sink go on; the link is re-made when the viewer comes back.  Not
thread-safe: the caller holds its lock.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from streamid.viz.reports import VizSettings, parse_rerun_url
from streamid.viz.rrd_files import Segments

__all__ = ["Link", "Sinks", "quiet_disconnect"]

_log = logging.getLogger("streamid.viz.rerun_view")


class Link(Protocol):
    """One recording stream with one sink."""

    rec: Any
    kind: str
    path: str | None

    def reopen(self, path: str) -> None:
        """Close the file (footer written) and go on in ``path``, on the same recording stream."""


def quiet_disconnect(rec: Any) -> None:
    """Flush and close ``rec``'s sink (the .rrd footer is written); never raises."""
    try:
        rec.disconnect()
    except Exception:  # noqa: BLE001
        pass


class Sinks:
    """The links of one recording, opened from ``settings`` by :meth:`open` (failures are warned once, never raised).

    ``open_link(kind, path)`` makes a link; ``greet(link)`` sends what a fresh
    link needs first (series styles, blueprint).
    """

    def __init__(self, settings: VizSettings, open_link: Callable[[str, str | None], Link],
                 greet: Callable[[Link], None]) -> None:
        self.settings = settings
        self._open, self._greet = open_link, greet
        self.warned: set[str] = set()
        self.file: Link | None = None
        self.serve: Link | None = None
        self.live: Link | None = None
        self.segments: Segments | None = None
        self._next_probe = 0.0

    def open(self) -> Sinks:
        """Open the configured sinks (the file, the served endpoint, the viewer link if one answers)."""
        settings, open_link = self.settings, self._open
        if settings.rrd is not None:
            try:
                self.file = open_link("file", settings.rrd)
                self.segments = Segments(settings.rrd, rotate_mb=settings.rrd_rotate_mb, keep=settings.rrd_keep,
                                         rotate_s=settings.rrd_rotate_s if settings.rrd_rotate_mb else None,
                                         max_mb=settings.rrd_max_mb)
                self._remove_stale()
            except Exception as exc:  # noqa: BLE001 - an unwritable path must not stop identification
                self.warn_once("file", f"rerun file {settings.rrd!r} could not be opened ({exc}); no .rrd is written")
        if settings.serve_port is not None:
            try:
                self.serve = open_link("serve", None)
            except Exception as exc:  # noqa: BLE001 - a port in use must not stop identification
                self.warn_once("serve", f"rerun endpoint on port {settings.serve_port} could not be served ({exc})")
        self.probe(force=True)
        return self

    def warn_once(self, key: str, message: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            _log.warning("%s", message)

    # ---------------------------------------------------------------- viewer link
    def probe(self, *, force: bool = False) -> None:
        """Check the viewer link of ``connect``; make or drop it."""
        url = self.settings.connect
        if url is None:
            return
        now = time.monotonic()
        if not force and now < self._next_probe:
            return
        self._next_probe = now + self.settings.probe_every_s
        host, port = parse_rerun_url(url)
        try:
            with socket.create_connection((host, port), timeout=0.2):
                up = True
        except OSError:
            up = False
        if up and self.live is None:
            try:
                self.live = self._open("live", None)
            except Exception as exc:  # noqa: BLE001
                self.warn_once("live", f"rerun viewer at {url} refused the connection ({exc}); continuing without it")
                return
            self.warned.discard("live")
            _log.info("streaming diagnostics to the rerun viewer at %s", url)
            self._greet(self.live)
        elif not up:
            if self.live is not None:
                self.warn_once("live", f"rerun viewer at {url} went away; identification continues without it")
                self.drop_live()
            else:
                self.warn_once("live", f"no rerun viewer at {url}; identification continues without it")

    def drop_live(self) -> None:
        live, self.live = self.live, None
        if live is None:
            return
        # the SDK waits up to 5 s for a lost viewer: never on the caller's thread
        threading.Thread(target=quiet_disconnect, args=(live.rec,), daemon=True, name="rerun-drop").start()

    def links(self) -> list[Link]:
        """The links to draw into now (the viewer link probed first)."""
        self.probe()
        return [lk for lk in (self.file, self.serve, self.live) if lk is not None]

    # ---------------------------------------------------------------- .rrd segments
    def _remove_stale(self) -> None:
        """Remove ``<stem>.NNN.rrd`` of an earlier run: ``<stem>.rrd`` was just overwritten, they would mix runs."""
        assert self.segments is not None
        stale = self.segments.stale()
        for p in stale:
            try:
                os.unlink(p)
            except OSError:
                pass
        if stale:
            _log.warning("removed %d .rrd segments of an earlier run (%s ... %s)", len(stale), stale[0].name,
                         stale[-1].name)

    def wrote(self) -> None:
        """Something was drawn: close the open .rrd segment (footer written) and continue in the next, if due."""
        if self.segments is not None:
            self.segments.dirty = True
        self.rotate_if_due()

    def rotate_if_due(self) -> None:
        """Close the open .rrd segment (footer written) and continue in the next, if due (also when idle)."""
        seg, old = self.segments, self.file
        if seg is None or old is None or not seg.due():
            return
        path, before = seg.next_path(), old.path
        t0 = time.perf_counter()
        try:
            # the same recording stream goes on in a new file sink: a new stream per segment would leave two
            # SDK threads behind each time (measured: +2 threads per RecordingStream, even after disconnect)
            old.reopen(str(path))
        except Exception as exc:  # noqa: BLE001
            self.warn_once("rotate", f"rerun file rotation to {str(path)!r} failed ({exc}); continuing in {before!r}")
            seg.opened_s = time.monotonic()  # retry one period later, not on every call
            return
        gone = seg.rotated(path)
        self._greet(old)
        _log.debug("rerun diagnostics continue in %s (%s closed in %.4f s)", path, before, time.perf_counter() - t0)
        if gone:
            _log.info("removed %d old .rrd segments (%s ...; keep %d segments, %s MB): %d removed so far",
                      len(gone), gone[0].name, seg.keep, seg.max_mb, seg.removed)

    def files(self) -> list[str]:
        """The .rrd segments written and still kept (oldest first; the last one is open until :meth:`close`)."""
        return [str(p) for p in self.segments.kept] if self.segments is not None else []

    def stats(self) -> dict[str, int]:
        """The .rrd segments: kept, their bytes, rotations so far, segments and bytes removed (empty without a file)."""
        return self.segments.stats() if self.segments is not None else {}

    # ---------------------------------------------------------------- shutdown
    def flush(self, timeout_s: float = 1.0) -> None:
        """Push buffered data to the file and served sinks (bounded wait)."""
        for lk in (self.file, self.serve):
            if lk is None:
                continue
            try:
                lk.rec.flush(timeout_sec=timeout_s)
            except Exception as exc:  # noqa: BLE001
                self.warn_once("flush", f"rerun flush incomplete ({exc})")

    def close(self, timeout_s: float = 1.0) -> None:
        """Flush and disconnect every sink (writes the ``.rrd`` footer) within about ``timeout_s``."""
        self.flush(timeout_s)
        links = [lk for lk in (self.file, self.serve) if lk is not None]
        self.file = self.serve = None
        self.drop_live()
        if not links:
            return
        done = threading.Event()

        def _disc() -> None:
            for lk in links:
                quiet_disconnect(lk.rec)
            done.set()

        threading.Thread(target=_disc, daemon=True, name="rerun-close").start()
        if not done.wait(max(timeout_s, 0.1)):
            _log.warning("rerun sinks did not close within %.1f s", timeout_s)
