"""Diagnostics in Rerun: the only module of streamid that imports ``rerun``.

:class:`Viz` owns its :class:`rerun.RecordingStream` (never the global one) and
draws, per stream, under ``streams/<stream>/``:

=============================  ===============================================================
``validation/{measured,osa,free_run}``  the validation part of the newest window and its predictions
``residual/{osa,free_run}``             measured minus prediction on the validation part
``correlation/<test>/{value,band}``     the five residual correlation tests with their ±95 % band
``fitness``                             best fitness per generation of the newest update
``history/{r2_osa,r2_fr}``              validation R^2 of every update (at the window's end time)
``history/{identification_s,latency_s}``  identification time, window close -> model published
``hysteresis/{measured,simulated}``     the input-output plane (first input vs output), normalised
``model``                               the selected lags and metrics (Markdown)
``events``                              text log: model published, bad input, gaps, backlog
=============================  ===============================================================

Data are logged on the ``stream_time`` timeline (the samples' own clock:
a duration, or a timestamp for Unix-epoch clocks).  A blueprint lays each
stream out as a tab; the time panel follows the newest data.

Sinks: an ``.rrd`` file (footer written on :meth:`Viz.close`; continued in
``<stem>.001.rrd``... once it passes ``rrd_rotate_mb``, because a file sink keeps
per-chunk metadata in memory for its footer), a served gRPC endpoint bound to
127.0.0.1 with a memory limit, and/or a viewer to connect to.  Each sink has
its own recording stream (same recording id), so a file can be rotated without
touching the served endpoint.  The SDK's gRPC client buffers
without bound while it cannot reach a viewer, so the connection is probed with
a plain TCP connect first: a viewer that is absent or goes away is reported once
(a warning) and the live link is dropped -- identification and the file sink go
on; the link is re-made when the viewer comes back.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from streamid.viz_types import (
    CorrelationCurve,
    UpdateReport,
    VizSettings,
    fmt_metric as _f,
    model_markdown,
    parse_rerun_url,
)

__all__ = ["VizSettings", "UpdateReport", "CorrelationCurve", "Viz", "parse_rerun_url"]

_log = logging.getLogger(__name__)

_COL_MEASURED = (230, 230, 230)
_COL_OSA = (66, 150, 250)
_COL_FR = (250, 140, 40)
_COL_BAND = (150, 150, 150, 70)
_EPOCH_NS = 10**17  # clocks beyond ~1973 are Unix time: use a timestamp timeline
_TIMELINE = "stream_time"


class _Link:
    """One RecordingStream with one kind of sink: ``file``, ``serve`` or ``live``."""

    def __init__(self, settings: VizSettings, recording_id: str, kind: str, path: str | None = None) -> None:
        self.rec = rr.RecordingStream(settings.application_id, recording_id=recording_id)
        self.kind = kind
        self.path = path
        if kind == "live":
            assert settings.connect is not None
            self.rec.connect_grpc(settings.connect)
        elif kind == "serve":
            assert settings.serve_port is not None
            self.rec.set_sinks(
                rr.GrpcServerSink(
                    bind_ip=settings.serve_bind, port=settings.serve_port, server_memory_limit=settings.serve_memory_limit
                )
            )
        else:
            assert path is not None
            self.rec.set_sinks(rr.FileSink(path))


def _rotated_path(path: str, index: int) -> str:
    p = Path(path)
    return str(p.with_name(f"{p.stem}.{index:03d}{p.suffix or '.rrd'}"))


class Viz:
    """Rerun diagnostics of the daemon (thread-safe, never raises on a sink failure).

    Parameters
    ----------
    settings
        Sinks; with none configured every method is a cheap no-op.
    """

    def __init__(self, settings: VizSettings) -> None:
        self.settings = settings
        self._lock = threading.RLock()
        self._rid = settings.recording_id or f"streamid-{time.time_ns()}"
        self._streams: dict[str, float | None] = {}
        self._time_kind: str | None = None
        self._warned: set[str] = set()
        self._closed = False
        self._file: _Link | None = None
        self._serve: _Link | None = None
        self._live: _Link | None = None
        self._files: deque[str] = deque()
        self._rotations = 0
        self._next_probe = 0.0
        if settings.rrd is not None:
            try:
                self._file = _Link(settings, self._rid, "file", settings.rrd)
                self._files.append(settings.rrd)
            except Exception as exc:  # noqa: BLE001 - an unwritable path must not stop identification
                self._warn_once("file", f"rerun file {settings.rrd!r} could not be opened ({exc}); no .rrd is written")
        if settings.serve_port is not None:
            try:
                self._serve = _Link(settings, self._rid, "serve")
            except Exception as exc:  # noqa: BLE001 - a port in use must not stop identification
                self._warn_once("serve", f"rerun endpoint on port {settings.serve_port} could not be served ({exc})")
        self._probe(force=True)

    # ---------------------------------------------------------------- sinks
    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            _log.warning("%s", message)

    def _probe(self, *, force: bool = False) -> None:
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
        if up and self._live is None:
            try:
                self._live = _Link(self.settings, self._rid, "live")
            except Exception as exc:  # noqa: BLE001
                self._warn_once("live", f"rerun viewer at {url} refused the connection ({exc}); continuing without it")
                return
            self._warned.discard("live")
            _log.info("streaming diagnostics to the rerun viewer at %s", url)
            self._send_all_styles(self._live)
            self._send_blueprint_to(self._live)
        elif not up:
            if self._live is not None:
                self._warn_once("live", f"rerun viewer at {url} went away; identification continues without it")
                self._drop_live()
            else:
                self._warn_once("live", f"no rerun viewer at {url}; identification continues without it")

    def _drop_live(self) -> None:
        live, self._live = self._live, None
        if live is None:
            return
        # the SDK waits up to 5 s for a lost viewer: never on the caller's thread
        threading.Thread(target=_quiet_disconnect, args=(live.rec,), daemon=True, name="rerun-drop").start()

    def _links(self) -> list[_Link]:
        self._probe()
        return [lk for lk in (self._file, self._serve, self._live) if lk is not None]

    def _maybe_rotate(self) -> None:
        """Continue the .rrd in a new file once it passed ``rrd_rotate_mb`` (footer written)."""
        lim, old = self.settings.rrd_rotate_mb, self._file
        if lim is None or old is None or old.path is None:
            return
        try:
            if os.path.getsize(old.path) < lim * 1e6:
                return
        except OSError:
            return
        self._rotations += 1
        path = _rotated_path(self.settings.rrd or old.path, self._rotations)
        try:
            new = _Link(self.settings, self._rid, "file", path)
        except Exception as exc:  # noqa: BLE001
            self._warn_once("rotate", f"rerun file rotation to {path!r} failed ({exc}); continuing in {old.path!r}")
            return
        try:
            old.rec.log("events", rr.TextLog(f"continued in {path}"))
            old.rec.flush(timeout_sec=1.0)
        except Exception:  # noqa: BLE001
            pass
        _quiet_disconnect(old.rec)
        self._file = new
        self._files.append(path)
        while len(self._files) > self.settings.rrd_keep:
            gone = self._files.popleft()
            try:
                os.unlink(gone)
            except OSError:
                pass
        self._send_all_styles(new)
        self._send_blueprint_to(new)
        new.rec.log("events", rr.TextLog(f"continued from {old.path}"))
        _log.info("rerun diagnostics continue in %s", path)

    @property
    def files(self) -> list[str]:
        """The .rrd files written so far and still kept (oldest first)."""
        return list(self._files)

    def _each(self, fn: Callable[[rr.RecordingStream], None]) -> None:
        with self._lock:
            if self._closed:
                return
            for lk in self._links():
                try:
                    fn(lk.rec)
                except Exception as exc:  # noqa: BLE001 - diagnostics never stop the daemon
                    self._warn_once(f"log:{type(exc).__name__}", f"rerun logging failed ({exc}); continuing")

    # ----------------------------------------------------------------- time
    def _tkind(self, t_ns: int) -> str:
        if self._time_kind is None:
            self._time_kind = "timestamp" if abs(t_ns) >= _EPOCH_NS else "duration"
        return self._time_kind

    def _set_time(self, rec: rr.RecordingStream, t_ns: int) -> None:
        if self._tkind(t_ns) == "timestamp":
            rec.set_time(_TIMELINE, timestamp=np.datetime64(int(t_ns), "ns"))
        else:
            rec.set_time(_TIMELINE, duration=np.timedelta64(int(t_ns), "ns"))

    def _time_column(self, t_ns: np.ndarray) -> rr.TimeColumn:
        t = np.asarray(t_ns, dtype=np.int64)
        if self._tkind(int(t[0])) == "timestamp":
            return rr.TimeColumn(_TIMELINE, timestamp=t.astype("datetime64[ns]"))
        return rr.TimeColumn(_TIMELINE, duration=t.astype("timedelta64[ns]"))

    # ------------------------------------------------------------- blueprint
    def add_stream(self, stream: str, *, validation_span_s: float | None = None) -> None:
        """Declare a stream (its tab in the blueprint and its series styles)."""
        with self._lock:
            if stream in self._streams and self._streams[stream] == validation_span_s:
                return
            self._streams[stream] = validation_span_s
            for lk in self._links():
                self._send_styles(lk.rec, stream)
                self._send_blueprint_to(lk)

    def _send_all_styles(self, link: _Link) -> None:
        for stream in self._streams:
            self._send_styles(link.rec, stream)

    def _send_styles(self, rec: rr.RecordingStream, stream: str) -> None:
        base = f"streams/{stream}"
        styles = {
            "validation/measured": (_COL_MEASURED, "measured"),
            "validation/osa": (_COL_OSA, "one step ahead"),
            "validation/free_run": (_COL_FR, "free run"),
            "residual/osa": (_COL_OSA, "one step ahead"),
            "residual/free_run": (_COL_FR, "free run"),
            "history/r2_osa": (_COL_OSA, "R² one step ahead (validation)"),
            "history/r2_fr": (_COL_FR, "R² free run (validation)"),
            "history/identification_s": ((120, 200, 120), "identification time [s]"),
            "history/latency_s": ((200, 120, 200), "window closed -> model published [s]"),
        }
        try:
            for path, (col, name) in styles.items():
                rec.log(f"{base}/{path}", rr.SeriesLines(colors=[col], names=name, widths=1.5), static=True)
        except Exception as exc:  # noqa: BLE001
            self._warn_once("styles", f"rerun styles not sent ({exc})")

    def blueprint(self) -> rrb.Blueprint:
        """The layout: one tab per stream."""
        tabs = [self._stream_layout(s, span) for s, span in sorted(self._streams.items())]
        if not tabs:
            tabs = [rrb.TextLogView(origin="events", name="events")]
        root = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs)
        return rrb.Blueprint(
            root,
            rrb.TimePanel(state="collapsed", play_state="following"),
            rrb.BlueprintPanel(state="hidden"),
            rrb.SelectionPanel(state="hidden"),
            auto_views=False,
        )

    def _stream_layout(self, stream: str, span_s: float | None) -> rrb.Container:
        base = f"streams/{stream}"
        ranges: list[Any] = []
        if span_s is not None and span_s > 0:
            start = rrb.TimeRangeBoundary.cursor_relative(seconds=-1.02 * span_s)
            ranges = [rrb.VisibleTimeRange(_TIMELINE, start=start, end=rrb.TimeRangeBoundary.cursor_relative())]
        legend = rrb.PlotLegend(corner="LeftTop", visible=True)
        no_legend = rrb.PlotLegend(visible=False)
        tests = ("ee", "ue", "e_eu", "u2_e", "u2_e2")
        corr = [
            rrb.BarChartView(origin=f"{base}/correlation/{t}", name=_TEST_LABELS[t], plot_legend=no_legend) for t in tests
        ]
        return rrb.Vertical(
            rrb.Horizontal(
                rrb.TimeSeriesView(origin=f"{base}/validation", name=f"{stream}: validation part, measured vs predicted",
                                   plot_legend=legend, time_ranges=ranges or None),
                rrb.TimeSeriesView(origin=f"{base}/residual", name="residuals (validation)", plot_legend=legend,
                                   time_ranges=ranges or None),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(*corr, name="residual correlation tests (±95 %)"),
            rrb.Horizontal(
                rrb.BarChartView(origin=f"{base}/fitness", name="fitness per generation",
                                 plot_legend=no_legend),
                rrb.TimeSeriesView(origin=f"{base}/history", contents=[f"{base}/history/r2_osa", f"{base}/history/r2_fr"],
                                   name="R² across updates", plot_legend=legend),
                rrb.TimeSeriesView(origin=f"{base}/history",
                                   contents=[f"{base}/history/identification_s", f"{base}/history/latency_s"],
                                   name="update time [s]", plot_legend=legend),
                rrb.Spatial2DView(origin=f"{base}/hysteresis", name="input-output plane (normalised)"),
                column_shares=[2, 2, 2, 2],
            ),
            rrb.Horizontal(
                rrb.TextDocumentView(origin=f"{base}/model", name="model"),
                rrb.TextLogView(origin=f"{base}/events", name="events"),
                column_shares=[1, 2],
            ),
            row_shares=[3, 2, 3, 2],
            name=stream,
        )

    def _send_blueprint_to(self, link: _Link) -> None:
        try:
            link.rec.send_blueprint(self.blueprint())
        except Exception as exc:  # noqa: BLE001
            self._warn_once("blueprint", f"rerun blueprint not sent ({exc})")

    # ---------------------------------------------------------------- logging
    def log_event(self, stream: str | None, text: str, *, level: str = "INFO", t_ns: int | None = None) -> None:
        """A line in the stream's (or the daemon's) event log."""
        path = f"streams/{stream}/events" if stream is not None else "events"

        def fn(rec: rr.RecordingStream) -> None:
            if t_ns is not None:
                self._set_time(rec, t_ns)
            rec.log(path, rr.TextLog(text, level=level))

        self._each(fn)

    def log_update(self, r: UpdateReport) -> None:
        """Draw one identification update."""
        self._each(lambda rec: self._draw(rec, r))
        with self._lock:
            if not self._closed:
                self._maybe_rotate()

    def _draw(self, rec: rr.RecordingStream, r: UpdateReport) -> None:
        base = f"streams/{r.stream}"
        n = len(r.y_val)
        if n:
            step = max(1, -(-n // self.settings.max_points))  # decimate long windows for drawing
            t = r.val_t0_ns + np.arange(0, n, step, dtype=np.int64) * np.int64(r.period_ns)
            tcol = self._time_column(t)
            y, osa, fr = (np.asarray(a, dtype=np.float64)[::step] for a in (r.y_val, r.osa_val, r.fr_val))
            for name, v in (("measured", y), ("osa", osa), ("free_run", fr)):
                rec.send_columns(f"{base}/validation/{name}", indexes=[tcol], columns=rr.Scalars.columns(scalars=_finite(v)))
            for name, v in (("osa", y - osa), ("free_run", y - fr)):
                rec.send_columns(f"{base}/residual/{name}", indexes=[tcol], columns=rr.Scalars.columns(scalars=_finite(v)))
        self._set_time(rec, r.window_end_ns)
        for c in r.correlations:
            lags = np.asarray(c.lags, dtype=np.float64)
            w = np.ones_like(lags)
            rec.log(f"{base}/correlation/{c.name}/band", rr.BarChart(np.full(lags.size, c.band), abscissa=lags, widths=w, color=_COL_BAND))
            rec.log(f"{base}/correlation/{c.name}/band_low", rr.BarChart(np.full(lags.size, -c.band), abscissa=lags, widths=w, color=_COL_BAND))
            rec.log(f"{base}/correlation/{c.name}/value", rr.BarChart(_finite(c.values), abscissa=lags, widths=0.35 * w, color=_COL_OSA))
        if len(r.fitness):
            rec.log(f"{base}/fitness", rr.BarChart(_finite(r.fitness), color=(120, 200, 120)))
        for name, v in (("r2_osa", r.metrics.get("r2_osa_val")), ("r2_fr", r.metrics.get("r2_fr_val"))):
            if v is not None and math.isfinite(v):
                rec.log(f"{base}/history/{name}", rr.Scalars(max(v, -1.0)))
        rec.log(f"{base}/history/identification_s", rr.Scalars(r.identification_s))
        if r.latency_s is not None:
            rec.log(f"{base}/history/latency_s", rr.Scalars(r.latency_s))
        if n and len(r.u_val) == n:
            self._draw_plane(rec, base, r)
        rec.log(f"{base}/model", rr.TextDocument(model_markdown(r), media_type="text/markdown"))
        verdict = "published" if r.accepted else "REJECTED"
        level = "INFO" if r.accepted else "WARN"
        rec.log(
            f"{base}/events",
            rr.TextLog(
                f"model v{r.version} {verdict} ({'warm' if r.warm else 'cold'}, G={r.generations}, "
                f"{r.identification_s:.2f} s): R² val OSA {_f(r.metrics.get('r2_osa_val'))} "
                f"FR {_f(r.metrics.get('r2_fr_val'))}{'; ' + r.note if r.note else ''}",
                level=level,
            ),
        )

    def _draw_plane(self, rec: rr.RecordingStream, base: str, r: UpdateReport) -> None:
        step = max(1, -(-len(r.u_val) // self.settings.max_points))
        u = np.asarray(r.u_val, dtype=np.float64)[::step]
        ys = [np.asarray(r.y_val, dtype=np.float64)[::step], np.asarray(r.fr_val, dtype=np.float64)[::step]]
        ok = np.isfinite(ys[1])
        ulo, uhi = float(u.min()), float(u.max())
        yall = np.concatenate([ys[0], ys[1][ok]])
        ylo, yhi = float(yall.min()), float(yall.max())
        if not (uhi > ulo and yhi > ylo):
            return
        sx, sy = 200.0, 150.0

        def xy(yv: np.ndarray, mask: np.ndarray) -> np.ndarray:
            x = (u[mask] - ulo) / (uhi - ulo) * 2 - 1
            yy = (yv[mask] - ylo) / (yhi - ylo) * 2 - 1
            return np.column_stack([x * sx, -yy * sy])

        allm = np.ones(u.size, dtype=bool)
        rec.log(f"{base}/hysteresis/measured", rr.LineStrips2D([xy(ys[0], allm)], colors=[_COL_MEASURED], radii=0.6))
        rec.log(f"{base}/hysteresis/simulated", rr.LineStrips2D([xy(ys[1], ok)], colors=[_COL_FR], radii=0.6))
        rec.log(
            f"{base}/hysteresis/legend",
            rr.Points2D([[-sx + 40, -sy - 30], [sx - 40, -sy - 30]], radii=0.1, colors=[_COL_MEASURED, _COL_FR],
                        labels=["measured", "free run"], show_labels=True),
        )
        rec.log(
            f"{base}/hysteresis/frame",
            rr.Boxes2D(mins=[[-sx, -sy]], sizes=[[2 * sx, 2 * sy]], colors=[(90, 90, 90)], radii=0.4),
        )
        rec.log(
            f"{base}/hysteresis/axes",
            rr.Points2D(
                [[0, sy + 22], [-sx - 50, 0], [-sx + 20, sy + 22], [sx - 20, sy + 22], [-sx - 50, sy - 10], [-sx - 50, -sy + 10]],
                radii=0.1,
                colors=[(200, 200, 200)],
                labels=[r.input_name, r.output_name, f"{ulo:.3g}", f"{uhi:.3g}", f"{ylo:.3g}", f"{yhi:.3g}"],
                show_labels=True,
            ),
        )

    # ---------------------------------------------------------------- shutdown
    def flush(self, timeout_s: float = 1.0) -> None:
        """Push buffered data to the file and served sinks (bounded wait)."""
        with self._lock:
            for lk in (self._file, self._serve):
                if lk is None:
                    continue
                try:
                    lk.rec.flush(timeout_sec=timeout_s)
                except Exception as exc:  # noqa: BLE001
                    self._warn_once("flush", f"rerun flush incomplete ({exc})")

    def close(self, timeout_s: float = 1.0) -> None:
        """Flush and disconnect every sink (writes the ``.rrd`` footer); idempotent."""
        with self._lock:
            if self._closed:
                return
            self.flush(timeout_s)
            self._closed = True
            links = [lk for lk in (self._file, self._serve) if lk is not None]
            self._file = self._serve = None
            self._drop_live()
        if links:
            done = threading.Event()

            def _disc() -> None:
                for lk in links:
                    _quiet_disconnect(lk.rec)
                done.set()

            threading.Thread(target=_disc, daemon=True, name="rerun-close").start()
            if not done.wait(max(timeout_s, 0.1)):
                _log.warning("rerun sinks did not close within %.1f s", timeout_s)


_TEST_LABELS = {
    "ee": "φ_ξξ(τ)",
    "ue": "φ_uξ(τ)",
    "e_eu": "φ_ξ(ξu)(τ)",
    "u2_e": "φ_(u²)'ξ(τ)",
    "u2_e2": "φ_(u²)'ξ²(τ)",
}


def _quiet_disconnect(rec: rr.RecordingStream) -> None:
    try:
        rec.disconnect()
    except Exception:  # noqa: BLE001
        pass


def _finite(v: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return np.where(np.isfinite(a), a, np.nan)




def rerun_cli() -> str:
    """Path of the ``rerun`` command that ships with rerun-sdk (beside the interpreter in a venv)."""
    import shutil
    import sys

    beside = Path(sys.executable).parent / "rerun"
    if beside.exists():
        return str(beside)
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("the `rerun` command of rerun-sdk was not found beside Python or on PATH")
    return found


def screenshot(rrd: str | os.PathLike[str], png: str | os.PathLike[str], *, window_size: str = "1280x800",
               timeout_s: float = 90.0) -> Path:
    """Render ``rrd`` with the real Rerun viewer, headless, into ``png``.

    The recording is first compacted with ``rerun rrd optimize`` (a daemon's
    recording has thousands of small chunks; the viewer takes its shot after a
    few frames, before those are all loaded) and then piped to the viewer's
    standard input.  Without
    a GPU the viewer needs a Vulkan software rasteriser: on Debian/Ubuntu
    ``apt-get install mesa-vulkan-drivers``.

    Raises
    ------
    RuntimeError
        If the viewer fails or writes no picture (the message says why and what to install).
    """
    import subprocess

    out = Path(png)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.exists():
        out.unlink()
    import tempfile

    cmd = [rerun_cli(), "--headless", "--screenshot-to", str(out), "--window-size", window_size,
           "--bind", "127.0.0.1", "-"]
    with tempfile.TemporaryFile() as compact:
        try:
            opt = subprocess.run([rerun_cli(), "rrd", "optimize", str(rrd)], stdout=compact,
                                 stderr=subprocess.PIPE, text=False, timeout=timeout_s)
            if opt.returncode != 0:
                raise RuntimeError(f"`rerun rrd optimize {rrd}` failed: {opt.stderr.decode(errors='replace')[-500:]}")
            compact.seek(0)
            proc = subprocess.run(cmd, stdin=compact, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired as exc:
            raise RuntimeError(f"the Rerun viewer did not finish the screenshot within {timeout_s:.0f} s") from exc
    if proc.returncode != 0 or not out.exists() or out.stat().st_size == 0:
        tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-5:]
        raise RuntimeError(
            "the Rerun viewer could not render the screenshot (exit code "
            f"{proc.returncode}); without a GPU it needs `apt-get install mesa-vulkan-drivers`. Viewer said: "
            + " | ".join(tail)
        )
    return out
