"""Diagnostics in Rerun: the only module of streamid that imports ``rerun``.

:class:`Viz` owns its :class:`rerun.RecordingStream` (never the global one) and
draws, per stream, under ``streams/<stream>/``:

``plot/validation/*``
    the newest update: measured vs one-step-ahead and free-run predictions on
    the validation part (a 2-D figure: lines, grid, ticks, legend)
``plot/residual/*``
    the newest update: measured minus predictions on the validation part
``plot/fitness/*``
    best fitness per generation on a log scale: the latest cold run, then the
    newest update
``hysteresis/*``
    the input-output plane (first input vs output), measured and free run
``correlation/<test>/{value,outside,band,band_low}``
    the five residual correlation tests; values outside the ±95 % band again in red
``history/{r2_osa,r2_fr,identification_s,latency_s}``
    validation R², identification time and window-closed-to-published time of
    every update (at the window's end)
``model``, ``events``
    the newest model (lags, R², share of lags inside each band; Markdown) and a
    text log (model published, bad input, gaps, backlog)
``validation/*``, ``residual/*``, ``fitness``
    the validation part and residuals as scalars on the stream's clock, and the
    raw best fitness per generation: data for other views and tools, not in the
    layout

Data are logged on the ``stream_time`` timeline (the samples' own clock: a
duration, or a timestamp for Unix-epoch clocks).  One recording has one time
cursor for all its streams, whose clocks need not agree, so everything that
shows "the newest update" is *latest-at* (bar charts, text, and 2-D figures
laid out by :mod:`streamid.viz.figures`) and the time series (history) show their
whole range: wherever the cursor stands, every stream's tab shows that
stream's newest update at or before it.  The blueprint lays each stream out as
a tab (in the order the streams were declared) and the time panel follows the
newest data.  :func:`screenshot` renders an ``.rrd`` with the real viewer.

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

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from streamid.viz.figures import COL_FR, COL_MEASURED, COL_OSA, CANVAS, Figure, fitness_figure, plane_figure, validation_figures
from streamid.viz.screenshot import render, rerun_cli
from streamid.viz.reports import (
    TEST_LABELS as _TEST_LABELS,
    UpdateReport,
    VizSettings,
    fmt_metric as _f,
    model_markdown,
    parse_rerun_url,
)

__all__ = ["VizSettings", "UpdateReport", "Viz", "parse_rerun_url", "screenshot", "rerun_cli"]

_log = logging.getLogger(__name__)

_COL_MEASURED, _COL_OSA, _COL_FR = COL_MEASURED, COL_OSA, COL_FR
_COL_BAND = (150, 150, 150, 50)
_COL_OUTSIDE = (240, 60, 60)
_COL_GRID = (58, 58, 58)
_COL_FRAME = (110, 110, 110)
_COL_MARK = (150, 150, 150)
#: the figures' series keys (a key missing from an update's figure is cleared)
_FIGURE_KEYS = {"validation": ("measured", "osa", "free_run"), "residual": ("osa", "free_run"),
                "fitness": ("cold", "newest"), "plane": ("measured", "simulated")}
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
        self._streams: dict[str, None] = {}  # declared streams, in order (an ordered set)
        self._cold: dict[str, tuple[int, np.ndarray]] = {}  # latest cold run's (version, fitness) per stream
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
    def add_stream(self, stream: str) -> None:
        """Declare a stream: its tab in the blueprint (tabs in declaration order) and its series styles."""
        with self._lock:
            if stream in self._streams:
                return
            self._streams[stream] = None
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
        """The layout: one tab per stream, in declaration order."""
        tabs: list[rrb.Container | rrb.View] = [self._stream_layout(s) for s in self._streams]
        if not tabs:
            tabs = [rrb.TextLogView(origin="events", name="events")]
        root = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs, active_tab=0)
        return rrb.Blueprint(
            root,
            rrb.TimePanel(state="collapsed", timeline=_TIMELINE, play_state="following"),
            rrb.BlueprintPanel(state="hidden"),
            rrb.SelectionPanel(state="hidden"),
            auto_views=False,
        )

    def _stream_layout(self, stream: str) -> rrb.Container:
        base = f"streams/{stream}"
        legend = rrb.PlotLegend(corner="LeftBottom", visible=True)
        legend_top = rrb.PlotLegend(corner="RightTop", visible=True)
        no_legend = rrb.PlotLegend(visible=False)
        tests = ("ee", "ue", "e_eu", "u2_e", "u2_e2")
        corr = [
            rrb.BarChartView(origin=f"{base}/correlation/{t}", name=_TEST_LABELS[t], plot_legend=no_legend) for t in tests
        ]

        def fig(path: str, kind: str, name: str) -> rrb.Spatial2DView:
            w, h = CANVAS[kind]
            return rrb.Spatial2DView(origin=f"{base}/{path}", name=name,
                                     visual_bounds=rrb.VisualBounds2D(x_range=[0.0, w], y_range=[0.0, h]))

        history = f"{base}/history"
        return rrb.Vertical(
            rrb.Horizontal(
                fig("plot/validation", "validation", f"{stream}: newest model on the validation part (held out)"),
                fig("plot/residual", "residual", "residuals on the validation part"),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(*corr, name="residual correlation tests (±95 % band; red: outside)"),
            rrb.Horizontal(
                fig("plot/fitness", "fitness", "best fitness per generation"),
                rrb.TimeSeriesView(origin=history, contents=[f"{history}/r2_osa", f"{history}/r2_fr"],
                                   name="R² (validation) across updates", plot_legend=legend),
                rrb.TimeSeriesView(origin=history, contents=[f"{history}/identification_s", f"{history}/latency_s"],
                                   name="update time [s] across updates", plot_legend=legend_top),
                fig("hysteresis", "plane", "input-output plane"),
                column_shares=[1, 1, 1, 1],
            ),
            rrb.Horizontal(
                rrb.TextDocumentView(origin=f"{base}/model", name="newest model"),
                rrb.TextLogView(origin=f"{base}/events", name="events"),
                column_shares=[2, 3],
            ),
            row_shares=[30, 19, 29, 22],
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
        if n:  # the validation part as scalars on the stream's clock (data; the layout shows the figures)
            step = max(1, -(-n // self.settings.max_points))  # decimate long windows for drawing
            t = r.val_t0_ns + np.arange(0, n, step, dtype=np.int64) * np.int64(r.period_ns)
            tcol = self._time_column(t)
            y, osa, fr = (np.asarray(a, dtype=np.float64)[::step] for a in (r.y_val, r.osa_val, r.fr_val))
            for name, v in (("measured", y), ("osa", osa), ("free_run", fr)):
                rec.send_columns(f"{base}/validation/{name}", indexes=[tcol], columns=rr.Scalars.columns(scalars=_finite(v)))
            for name, v in (("osa", y - osa), ("free_run", y - fr)):
                rec.send_columns(f"{base}/residual/{name}", indexes=[tcol], columns=rr.Scalars.columns(scalars=_finite(v)))
        self._set_time(rec, r.window_end_ns)
        if n:
            fit, res = validation_figures(r, self.settings.max_points)
            self._log_figure(rec, f"{base}/plot/validation", fit, _FIGURE_KEYS["validation"])
            self._log_figure(rec, f"{base}/plot/residual", res, _FIGURE_KEYS["residual"])
            plane = plane_figure(r, self.settings.max_points)
            if plane is not None:
                self._log_figure(rec, f"{base}/hysteresis", plane, _FIGURE_KEYS["plane"])
        for c in r.correlations:
            lags = np.asarray(c.lags, dtype=np.float64)
            vals = _finite(c.values)
            w = np.ones_like(lags)
            outside = np.where(np.abs(vals) > c.band, vals, 0.0)
            rec.log(f"{base}/correlation/{c.name}/band", rr.BarChart(np.full(lags.size, c.band), abscissa=lags, widths=w, color=_COL_BAND))
            rec.log(f"{base}/correlation/{c.name}/band_low", rr.BarChart(np.full(lags.size, -c.band), abscissa=lags, widths=w, color=_COL_BAND))
            rec.log(f"{base}/correlation/{c.name}/value", rr.BarChart(vals, abscissa=lags, widths=0.4 * w, color=_COL_OSA))
            rec.log(f"{base}/correlation/{c.name}/outside", rr.BarChart(outside, abscissa=lags, widths=0.4 * w, color=_COL_OUTSIDE))
        if len(r.fitness):
            f = _finite(r.fitness)
            rec.log(f"{base}/fitness", rr.BarChart(f, color=(120, 200, 120)))
            with self._lock:
                if not r.warm:
                    self._cold[r.stream] = (r.version, f)
                cold = self._cold.get(r.stream)
            self._log_figure(rec, f"{base}/plot/fitness", fitness_figure((r.version, r.warm, f), cold),
                             _FIGURE_KEYS["fitness"])
        for name, metric in (("r2_osa", r.metrics.get("r2_osa_val")), ("r2_fr", r.metrics.get("r2_fr_val"))):
            if metric is not None and math.isfinite(metric):
                rec.log(f"{base}/history/{name}", rr.Scalars(max(metric, -1.0)))
        rec.log(f"{base}/history/identification_s", rr.Scalars(r.identification_s))
        if r.latency_s is not None:
            rec.log(f"{base}/history/latency_s", rr.Scalars(r.latency_s))
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

    @staticmethod
    def _log_figure(rec: rr.RecordingStream, path: str, fig: Figure, keys: Sequence[str]) -> None:
        """Draw a :class:`~streamid.viz.figures.Figure` under ``path``; series of ``keys`` it lacks are cleared."""
        thin = rr.Radius.ui_points(0.5)
        rec.log(f"{path}/grid", rr.LineStrips2D(list(fig.grid), colors=[_COL_GRID], radii=thin, draw_order=1.0))
        x0, y0, x1, y1 = fig.frame
        rec.log(f"{path}/frame", rr.Boxes2D(mins=[[x0, y0]], sizes=[[x1 - x0, y1 - y0]], colors=[_COL_FRAME],
                                             radii=thin, draw_order=2.0))
        rec.log(f"{path}/marks", rr.LineStrips2D(list(fig.marks), colors=[_COL_MARK], radii=rr.Radius.ui_points(0.75),
                                                  draw_order=3.0))
        drawn = set()
        for i, (key, color, width, strips) in enumerate(fig.lines):
            drawn.add(key)
            rec.log(f"{path}/{key}", rr.LineStrips2D(list(strips), colors=[color], radii=rr.Radius.ui_points(width / 2),
                                                      draw_order=10.0 + i))
        for key in keys:
            if key not in drawn:
                rec.log(f"{path}/{key}", rr.Clear(recursive=False))
        lab = fig.labels
        rec.log(f"{path}/labels", rr.Points2D([[la.x, la.y] for la in lab], radii=0.0, colors=[la.color for la in lab],
                                               labels=[la.text for la in lab], show_labels=True, draw_order=30.0))

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




def _quiet_disconnect(rec: rr.RecordingStream) -> None:
    try:
        rec.disconnect()
    except Exception:  # noqa: BLE001
        pass


def _finite(v: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return np.where(np.isfinite(a), a, np.nan)


def screenshot(
    rrd: str | os.PathLike[str],
    png: str | os.PathLike[str],
    *,
    window_size: str = "1280x800",
    timeout_s: float = 90.0,
    settle_s: float = 4.0,
) -> Path:
    """Render ``rrd`` with the real Rerun viewer, headless, into ``png`` (see :func:`streamid.viz.screenshot.render`)."""
    from rerun.experimental import ViewerClient

    return render(rrd, png, connect=ViewerClient.connect, window_size=window_size, timeout_s=timeout_s,
                  settle_s=settle_s)
