"""Diagnostics in Rerun: the only module of streamid that imports ``rerun``.

:class:`Viz` owns its :class:`rerun.RecordingStream` (never the global one) and
draws, per stream, under ``streams/<stream>/``:

``plot/validation/*``
    the newest update: measured vs one-step-ahead and free-run predictions on
    the validation part, and the free run's band when the model carries a
    prediction interval (a 2-D figure: lines, grid, ticks, legend)
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
    validation R² and identification time of every update (a rejected
    challenger's R² as ``rejected_r2_fr``, beside ``champion_r2_fr`` on the same
    data), and window-closed-to-published time of every published model (at the
    window's end)
``model``, ``events``
    the newest model (lags, R², share of lags inside each band; Markdown) and a
    text log (model published, bad input, gaps, backlog)
``validation/*`` (``lower``, ``upper``: the band), ``residual/*``, ``fitness``
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

Sinks (:mod:`streamid.viz.sinks`): an ``.rrd`` file (footer written on
:meth:`Viz.close`; continued in ``<stem>.001.rrd``... by size or time, old
segments removed past stated bounds: :mod:`streamid.viz.rrd_files`), a served
gRPC endpoint bound to 127.0.0.1 with a memory limit, and/or a viewer to
connect to (probed first; dropped and re-made as it goes and comes).  Each sink
has its own recording stream (same recording id), so a file can be rotated
without touching the served endpoint.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import rerun_bindings as rr_bindings

from streamid.viz.figures import COL_FR, COL_MEASURED, COL_OSA, CANVAS, Figure, fitness_figure, plane_figure, validation_figures
from streamid.viz.rrd_files import RepairReport, repair
from streamid.viz.sinks import Link, Sinks
from streamid.viz.screenshot import render, rerun_cli
from streamid.viz.reports import (
    SERIES_STYLES,
    TEST_LABELS as _TEST_LABELS,
    UpdateReport,
    VizSettings,
    fmt_metric as _f,
    model_markdown,
    run_text,
    parse_rerun_url,
)

__all__ = ["VizSettings", "UpdateReport", "Viz", "parse_rerun_url", "screenshot", "rerun_cli", "repair_rrd"]

_COL_MEASURED, _COL_OSA, _COL_FR = COL_MEASURED, COL_OSA, COL_FR
_COL_BAND = (150, 150, 150, 50)
_COL_OUTSIDE = (240, 60, 60)
_COL_GRID = (58, 58, 58)
_COL_FRAME = (110, 110, 110)
_COL_MARK = (150, 150, 150)
#: the figures' series keys (a key missing from an update's figure is cleared)
_FIGURE_KEYS = {"validation": ("band_fill", "band_lower", "band_upper", "measured", "osa", "free_run"),
                "residual": ("osa", "free_run"),
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

    def reopen(self, path: str) -> None:
        """Go on in the file ``path``: the SDK flushes the previous file, writes its footer and closes it first."""
        self.rec.set_sinks(rr.FileSink(path))
        self.path = path


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
        self._closed = False
        self._bp_stream: tuple[tuple[str, ...], rr.RecordingStream] | None = None  # (layout's streams, its stream)

        def open_link(kind: str, path: str | None) -> Link:
            return _Link(settings, self._rid, kind, path)

        self._sinks = Sinks(settings, open_link, self._greet)
        self._warn_once = self._sinks.warn_once
        self._sinks.open()
        self._stop = threading.Event()
        if self._sinks.segments is not None and self._sinks.segments.rotate_s is not None:
            threading.Thread(target=self._rotate_when_idle, args=(self._sinks.segments.rotate_s / 2,), daemon=True,
                             name="rerun-rotate").start()

    def _rotate_when_idle(self, period_s: float) -> None:
        """Close a segment that is due though nothing more is drawn: an idle daemon's .rrd all verifies."""
        while not self._stop.wait(period_s):
            with self._lock:
                if self._closed:
                    return
                self._sinks.rotate_if_due()

    @property
    def _live(self) -> Link | None:
        return self._sinks.live

    @property
    def files(self) -> list[str]:
        """The .rrd segments written so far and still kept (oldest first; the last one is open until :meth:`close`)."""
        with self._lock:
            return self._sinks.files()

    @property
    def file_stats(self) -> dict[str, int]:
        """The .rrd segments: kept, their bytes, rotations so far, segments and bytes removed (empty without a file)."""
        with self._lock:
            return self._sinks.stats()

    def _greet(self, link: Link) -> None:
        self._send_all_styles(link)
        self._send_blueprint_to(link)

    def _each(self, fn: Callable[[rr.RecordingStream], None]) -> None:
        with self._lock:
            if self._closed:
                return
            for lk in self._sinks.links():
                try:
                    fn(lk.rec)
                except Exception as exc:  # noqa: BLE001 - diagnostics never stop the daemon
                    self._warn_once(f"log:{type(exc).__name__}", f"rerun logging failed ({exc}); continuing")
            self._sinks.wrote()

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
            for lk in self._sinks.links():
                self._send_styles(lk.rec, stream)
                self._send_blueprint_to(lk)

    def _send_all_styles(self, link: Link) -> None:
        for stream in self._streams:
            self._send_styles(link.rec, stream)

    def _send_styles(self, rec: rr.RecordingStream, stream: str) -> None:
        base = f"streams/{stream}"
        try:
            for path, (col, name) in SERIES_STYLES.items():
                rec.log(f"{base}/{path}", rr.SeriesLines(colors=[col], names=name, widths=1.5), static=True)
        except Exception as exc:  # noqa: BLE001
            self._warn_once("styles", f"rerun styles not sent ({exc})")

    def blueprint(self) -> rrb.Blueprint:
        """The layout: one tab per stream, in declaration order."""
        tabs: list[rrb.Container | rrb.View] = [self._stream_layout(s) for s in self._streams]
        if not tabs:
            tabs = [rrb.TextLogView(origin="events", name="events")]
        # A stream with several outputs draws each in a tab "<stream>/<output>"; its own tab (configured streams get
        # one at start) then holds only its events, so the first tab shown is the first one that is not such a parent.
        names = list(self._streams)
        parents = {n.rsplit("/", 1)[0] for n in names if "/" in n}
        active = next((i for i, n in enumerate(names) if n not in parents), 0)
        root = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs, active_tab=active)
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
        layout = self.settings.layout
        title, served = {"daemon": ("champion on the held-out part when it won", "champion (the model served)"),
                         "identify": ("the kept model on the validation data", "the kept model"),
                         "validate": ("the model judged on this record", "the model judged")}[layout]
        plane = fig("hysteresis", "plane", "input-output plane")
        fitness = fig("plot/fitness", "fitness", "best fitness per generation")
        if layout == "validate":  # no identification ran: no fitness, no R² or time across updates
            third: list[rrb.View] = [plane]
        elif layout == "identify":  # one identification: no history across updates
            third = [fitness, plane]
        else:
            third = [
                fitness,
                rrb.TimeSeriesView(origin=history, contents=[f"{history}/{k}" for k in (
                    "r2_osa", "r2_fr", "champion_r2_fr", "rejected_r2_fr")],
                                   name="R² (held out): champions, re-validations, rejected", plot_legend=legend),
                rrb.TimeSeriesView(origin=history, contents=[f"{history}/identification_s", f"{history}/latency_s"],
                                   name="update time [s] across updates", plot_legend=legend_top),
                plane,
            ]
        return rrb.Vertical(
            rrb.Horizontal(
                fig("plot/validation", "validation", f"{stream}: {title}"),
                fig("plot/residual", "residual", "residuals on the validation part"),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(*corr, name="residual correlation tests (±95 % band; red: outside)"),
            rrb.Horizontal(*third, column_shares=[1] * len(third)),
            rrb.Horizontal(
                rrb.TextDocumentView(origin=f"{base}/model", name=served),
                rrb.TextLogView(origin=f"{base}/events", name="events"),
                column_shares=[2, 3],
            ),
            row_shares=[30, 19, 29, 22],
            name=stream,
        )

    def _send_blueprint_to(self, link: Link) -> None:
        """Send the layout, from one blueprint stream per layout (the streams declared so far).

        ``RecordingStream.send_blueprint`` makes a new blueprint stream on every call, and each
        leaves two SDK threads behind (measured, rerun-sdk 0.41): once per .rrd segment and per
        viewer reconnection that grew without bound.  The stream of the current layout is kept and
        its blueprint logged again into a fresh in-memory sink for each send.
        """
        try:
            key = tuple(self._streams)
            if self._bp_stream is None or self._bp_stream[0] != key:
                self._bp_stream = (key, rr.RecordingStream._from_native(rr_bindings.new_blueprint(
                    application_id=self.settings.application_id, make_default=False, make_thread_default=False,
                    default_enabled=True)))
            bps = self._bp_stream[1]
            memory = bps.memory_recording()
            bps.set_time("blueprint", sequence=0)
            self.blueprint()._log_to_stream(bps)
            bps.flush()
            rr_bindings.send_blueprint(memory.storage, True, True, recording=link.rec.to_native())
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

    def _draw(self, rec: rr.RecordingStream, r: UpdateReport) -> None:
        base = f"streams/{r.stream}"
        if not r.accepted:  # a rejected challenger: its figure and the champion's on the same data, no plots
            self._set_time(rec, r.window_end_ns)
            for name, metric in (("rejected_r2_fr", r.metrics.get("r2_fr_val")), ("champion_r2_fr", r.champion_r2_fr)):
                if metric is not None and math.isfinite(metric):
                    rec.log(f"{base}/history/{name}", rr.Scalars(max(metric, -1.0)))
            # the work spent, whatever the verdict: with only the accepted updates drawn, a champion that keeps
            # winning left the panel one line from its first run to its last publication
            rec.log(f"{base}/history/identification_s", rr.Scalars(r.identification_s))
            rec.log(f"{base}/events", rr.TextLog(
                f"challenger REJECTED ({run_text(r, ', ')}, {r.identification_s:.2f} s): R² val OSA "
                f"{_f(r.metrics.get('r2_osa_val'))} FR {_f(r.metrics.get('r2_fr_val'))}; {r.note}", level="INFO"))
            return
        n = len(r.y_val)
        if n:  # the validation part as scalars on the stream's clock (data; the layout shows the figures)
            step = max(1, -(-n // self.settings.max_points))  # decimate long windows for drawing
            t = r.val_t0_ns + np.arange(0, n, step, dtype=np.int64) * np.int64(r.period_ns)
            tcol = self._time_column(t)
            y, osa, fr = (np.asarray(a, dtype=np.float64)[::step] for a in (r.y_val, r.osa_val, r.fr_val))
            band = () if r.lower_val is None or r.upper_val is None else (
                ("lower", np.asarray(r.lower_val, dtype=np.float64)[::step]),
                ("upper", np.asarray(r.upper_val, dtype=np.float64)[::step]))  # the free run's band, if any
            for name, v in (("measured", y), ("osa", osa), ("free_run", fr), *band):
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
        if not r.judged_only:
            rec.log(f"{base}/history/identification_s", rr.Scalars(r.identification_s))
        if r.latency_s is not None:
            rec.log(f"{base}/history/latency_s", rr.Scalars(r.latency_s))
        rec.log(f"{base}/model", rr.TextDocument(model_markdown(r), media_type="text/markdown"))
        verdict = "published" if r.accepted else "REJECTED"
        level = "INFO" if r.accepted else "WARN"
        figures = (f"R² val OSA {_f(r.metrics.get('r2_osa_val'))} FR {_f(r.metrics.get('r2_fr_val'))}"
                   f"{'; ' + r.note if r.note else ''}")
        text = (f"the model judged on this record: {figures}" if r.judged_only else
                f"model v{r.version} {verdict} ({run_text(r, ', ')}, "
                f"{r.identification_s:.2f} s): {figures}")
        rec.log(f"{base}/events", rr.TextLog(text, level=level))

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
            self._sinks.flush(timeout_s)

    def close(self, timeout_s: float = 1.0) -> None:
        """Flush and disconnect every sink (writes the ``.rrd`` footer) within about ``timeout_s``; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
        self._sinks.close(timeout_s)


def _finite(v: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return np.where(np.isfinite(a), a, np.nan)


def screenshot(
    rrd: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    png: str | os.PathLike[str],
    *,
    window_size: str = "1280x800",
    timeout_s: float = 90.0,
    settle_s: float = 4.0,
) -> Path:
    """Render ``rrd`` (one .rrd or several, e.g. the segments of a recording) with the real Rerun viewer,
    headless, into ``png`` (see :func:`streamid.viz.screenshot.render`)."""
    from rerun.experimental import ViewerClient

    return render(rrd, png, connect=ViewerClient.connect, window_size=window_size, timeout_s=timeout_s,
                  settle_s=settle_s)


def count_chunks(path: str | os.PathLike[str]) -> int:
    """Data chunks of every recording in the .rrd at ``path`` (blueprints not counted)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(Path(path))
    return sum(len(reader.stream(store=entry).to_chunks()) for entry in reader.recordings())


def repair_rrd(src: str | os.PathLike[str], out: str | os.PathLike[str] | None = None, *,
               timeout_s: float = 300.0) -> RepairReport:
    """A verified copy of a damaged .rrd (see :func:`streamid.viz.rrd_files.repair`), chunks counted by the SDK."""
    return repair(src, out, rerun=rerun_cli(), count_chunks=count_chunks, timeout_s=timeout_s)
