"""Figures of the newest update, as plain 2-D geometry (no ``rerun`` import).

Why not Rerun time-series views for these: a time-series view plots what lies
in a time range around the viewer's time cursor, and one recording has one
cursor for all its streams.  Streams with different clocks (a replayed log
that starts at 0 next to a live device on Unix time, or two logs of different
lengths) end at different times on the shared timeline, so a cursor-relative
range shows nothing for every stream but the one that ended last.  The
newest update's validation part, residuals, fitness curve and input-output
plane are therefore drawn as *latest-at* 2-D figures (lines, a frame, a grid,
tick labels and a legend on a fixed canvas): wherever the cursor stands, each
stream shows its own newest update at or before it.

:func:`figure` lays out a plot; :mod:`streamid.viz.rerun_view` turns a :class:`Figure`
into ``LineStrips2D``/``Boxes2D``/``Points2D`` and the blueprint fixes each
view's visual bounds to the figure's canvas (x to the right, y downwards).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from streamid.viz.reports import UpdateReport

__all__ = [
    "Axis",
    "Figure",
    "Label",
    "Series",
    "figure",
    "nice_ticks",
    "log_ticks",
    "tick_text",
    "CANVAS",
    "validation_figures",
    "COL_BAND",
    "COL_BAND_FILL",
    "fitness_figure",
    "plane_figure",
    "clock_text",
]

RGB = tuple[int, int, int]

#: Canvas size (width, height) of each figure kind, about its panel's size in
#: points at the demo's 1280x800 window, so labels (drawn at a fixed size in
#: points) fit the plot.
CANVAS: dict[str, tuple[float, float]] = {
    "validation": (760.0, 200.0),
    "residual": (505.0, 200.0),
    "fitness": (310.0, 200.0),
    "plane": (310.0, 200.0),
}

_LEFT, _RIGHT, _TOP, _BOTTOM = 50.0, 12.0, 30.0, 24.0
_CHAR_W = 7.4  # approximate width of one label character in canvas units (labels have a fixed size in points)
_PAD = 16.0  # a label's box is this much wider than its text
_TEXT = (150, 150, 150)


@dataclass(frozen=True)
class Series:
    """One line of a figure: ``key`` names its entity, ``label`` its legend entry."""

    key: str
    label: str
    color: RGB
    x: np.ndarray
    y: np.ndarray
    width: float = 1.5


@dataclass(frozen=True)
class Axis:
    """Range and scale of one axis (``log``: base-10 logarithmic, lo > 0)."""

    lo: float
    hi: float
    log: bool = False
    scale: float = 1.0  # tick values are shown multiplied by this (e.g. 1000 for ms)


@dataclass(frozen=True)
class Label:
    """A text drawn centred under the point (x, y), in ``color``."""

    x: float
    y: float
    text: str
    color: RGB


@dataclass(frozen=True)
class Figure:
    """A plot in canvas coordinates (x to the right, y downwards).

    ``lines`` are ``(key, color, width, strips)``: a series broken at its
    non-finite values into polylines of shape (k, 2).
    """

    width: float
    height: float
    frame: tuple[float, float, float, float]
    grid: tuple[np.ndarray, ...]
    marks: tuple[np.ndarray, ...]
    lines: tuple[tuple[str, RGB, float, tuple[np.ndarray, ...]], ...]
    labels: tuple[Label, ...]


def nice_ticks(lo: float, hi: float, max_ticks: int = 6) -> np.ndarray:
    """Round tick values (steps of 1, 2, 2.5 or 5 x 10^k) inside [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.empty(0)
    raw = (hi - lo) / max(1, max_ticks - 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * mag >= raw * (1 - 1e-9))
    first = math.ceil(lo / step - 1e-9) * step
    ticks = first + step * np.arange(int(math.floor((hi - first) / step + 1e-9)) + 1)
    ticks[np.abs(ticks) < step * 1e-9] = 0.0
    return ticks


def log_ticks(lo: float, hi: float, max_ticks: int = 6) -> np.ndarray:
    """Ticks of a log axis: 1-2-5 per decade over wide ranges, round linear values over narrow ones."""
    if not (lo > 0 and hi > lo):
        return np.empty(0)
    if hi / lo < 10.0:
        return nice_ticks(lo, hi, max_ticks)
    out: list[float] = []
    for mults in ((1.0, 2.0, 5.0), (1.0,)):
        out = [m * 10.0**e for e in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1) for m in mults]
        out = [v for v in out if lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9)]
        if len(out) <= max_ticks:
            break
    if len(out) > max_ticks:  # many decades: every k-th decade
        k = math.ceil(len(out) / max_ticks)
        out = out[::k]
    return np.asarray(out, dtype=np.float64)


def tick_text(v: float, ticks: np.ndarray) -> str:
    """A tick value with as many decimals as the tick spacing needs (with a true minus sign)."""
    finite = np.sort(ticks[np.isfinite(ticks)])
    step = float(np.min(np.diff(finite))) if finite.size >= 2 else (abs(v) or 1.0)
    big = float(np.max(np.abs(finite))) if finite.size else abs(v)
    if big >= 1e5 or 0 < big < 1e-3 or not step > 0:
        s = f"{v:.3g}"
    else:
        dec = max(0, math.ceil(-math.log10(step) - 1e-9))
        while dec < 6 and abs(step * 10**dec - round(step * 10**dec)) > 1e-6 * max(1.0, step * 10**dec):
            dec += 1
        s = f"{v:.{dec}f}"
    return s.replace("-", "\u2212")


def data_range(arrays: Sequence[np.ndarray], *, pad: float = 0.06, symmetric: bool = False) -> tuple[float, float]:
    """[lo, hi] over the finite values of ``arrays``, padded; a constant gets a unit range."""
    vals = [np.asarray(a, dtype=np.float64) for a in arrays]
    vals = [a[np.isfinite(a)] for a in vals]
    vals = [a for a in vals if a.size]
    if not vals:
        return (-1.0, 1.0)
    lo = float(min(a.min() for a in vals))
    hi = float(max(a.max() for a in vals))
    if symmetric:
        m = max(abs(lo), abs(hi))
        lo, hi = -m, m
    if hi <= lo:
        d = abs(lo) * 0.1 or 1.0
        return (lo - d, hi + d)
    span = hi - lo
    return (lo - pad * span, hi + pad * span)


def figure(
    series: Sequence[Series],
    *,
    kind: str,
    x: Axis,
    y: Axis,
    note: str = "",
    x_unit: str = "",
    y_title: str = "",
    marks_x: Sequence[tuple[float, str]] = (),
    zero_line: bool = False,
) -> Figure:
    """Lay out ``series`` on the canvas of ``kind`` with ticks, a grid, a legend and a right-hand ``note``.

    Values outside the axes are clipped to the frame (a diverging free run
    stays visible as a line along the edge).  ``x_unit`` (the x axis' unit
    or name) is appended to the last x tick label; ``y_title`` leads the
    header row, before the legend; ``marks_x`` draws labelled vertical lines
    (e.g. where a warm start begins).
    """
    w, h = CANVAS[kind]
    x0, y0, x1, y1 = _LEFT, _TOP, w - _RIGHT, h - _BOTTOM

    def fx(v: np.ndarray) -> np.ndarray:
        return x0 + _frac(np.asarray(v, dtype=np.float64), x) * (x1 - x0)

    def fy(v: np.ndarray) -> np.ndarray:
        return y1 - _frac(np.asarray(v, dtype=np.float64), y) * (y1 - y0)

    labels: list[Label] = []
    grid: list[np.ndarray] = []
    xt = log_ticks(x.lo, x.hi) if x.log else nice_ticks(x.lo * x.scale, x.hi * x.scale, _max_x_ticks(w)) / x.scale
    left_free = math.inf  # x tick labels from the right; one that would overlap its right neighbour is left out
    for i in range(len(xt) - 1, -1, -1):
        px = float(fx(np.array([xt[i]]))[0])
        grid.append(np.array([[px, y0], [px, y1]]))
        text = tick_text(xt[i] * x.scale, xt * x.scale) + (f" {x_unit}" if x_unit and i == len(xt) - 1 else "")
        cx = min(px, x1 + _RIGHT - _half(text))
        if cx + _half(text) <= left_free - 2.0:
            labels.append(Label(cx, y1 + 1.0, text, _TEXT))
            left_free = cx - _half(text)
    yt = log_ticks(y.lo, y.hi, 5) if y.log else nice_ticks(y.lo * y.scale, y.hi * y.scale, 5) / y.scale
    for v in yt:
        py = float(fy(np.array([v]))[0])
        grid.append(np.array([[x0, py], [x1, py]]))
        text = tick_text(v * y.scale, yt * y.scale)
        labels.append(Label(x0 - 2.0 - _half(text), py - 10.0, text, _TEXT))
    marks: list[np.ndarray] = []
    if zero_line and y.lo < 0 < y.hi and not y.log:
        pz = float(fy(np.array([0.0]))[0])
        marks.append(np.array([[x0, pz], [x1, pz]]))
    for mx, text in marks_x:
        px = float(fx(np.array([mx]))[0])
        marks.append(np.array([[px, y0], [px, y1]]))
        right = px + 3.0 + 2 * _half(text) <= x1
        labels.append(Label(px + 3.0 + _half(text) if right else px - 3.0 - _half(text), y0 + 2.0, text, _TEXT))
    lines = []
    lx = 2.0
    if y_title:
        labels.append(Label(lx + _half(y_title), 2.0, y_title, _TEXT))
        lx += 2 * _half(y_title) + 6.0
    else:
        lx = x0 - 10.0
    for s in series:
        pts = np.column_stack([fx(s.x), fy(s.y)])
        lines.append((s.key, s.color, s.width, _strips(pts)))
        if s.label:
            labels.append(Label(lx + _half(s.label), 2.0, s.label, s.color))
            lx += 2 * _half(s.label) + 6.0
    if note and x1 + _RIGHT - 2.0 - 2 * _half(note) < lx:  # no room beside the legend: keep its [unit] part
        unit = re.search(r"\[[^\]]*\]", note)
        note = unit.group(0) if unit else ""
    if note and x1 + _RIGHT - 2.0 - 2 * _half(note) >= lx:
        labels.append(Label(x1 + _RIGHT - 2.0 - _half(note), 2.0, note, _TEXT))
    return Figure(w, h, (x0, y0, x1, y1), tuple(grid), tuple(marks), tuple(lines), tuple(labels))


def _max_x_ticks(width: float) -> int:
    return max(3, min(9, int(width // 50)))


def _half(text: str) -> float:
    """Half the width of a label's box (labels are centred on their point)."""
    return (_CHAR_W * len(text) + _PAD) / 2


def _frac(v: np.ndarray, ax: Axis) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        if ax.log:
            f = (np.log10(np.where(v > 0, v, np.nan)) - math.log10(ax.lo)) / (math.log10(ax.hi) - math.log10(ax.lo))
        else:
            f = (v - ax.lo) / (ax.hi - ax.lo)
    return np.clip(f, 0.0, 1.0)


def _strips(pts: np.ndarray) -> tuple[np.ndarray, ...]:
    """Split a polyline at its non-finite points; drop pieces of fewer than 2 points."""
    ok = np.all(np.isfinite(pts), axis=1)
    if ok.all():
        return (pts,) if len(pts) >= 2 else ()
    out = []
    idx = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
    for a, b in zip(idx[::2], idx[1::2]):
        if b - a >= 2:
            out.append(pts[a:b])
    return tuple(out)


# ------------------------------------------------------------------ the figures of one update
COL_MEASURED: RGB = (230, 230, 230)
COL_OSA: RGB = (66, 150, 250)
COL_FR: RGB = (250, 140, 40)
COL_BAND: RGB = (215, 150, 80)  # the free run's band: its edges
COL_BAND_FILL: RGB = (125, 80, 36)  # and its inside (a darker orange under the lines)
COL_COLD: RGB = (120, 200, 120)
COL_WARM: RGB = (235, 200, 70)
_EPOCH_NS = 10**17  # clocks beyond ~1973 are Unix time


def clock_text(t_ns: int) -> str:
    """A time of the stream's clock: seconds since its start, or UTC for Unix-time clocks."""
    if abs(t_ns) >= _EPOCH_NS:
        return str(np.datetime64(int(t_ns), "ns").astype("datetime64[ms]")).replace("T", " ") + " UTC"
    return f"{t_ns / 1e9:.3f} s"


def _decimate(n: int, max_points: int) -> int:
    return max(1, -(-n // max_points))


def validation_figures(r: UpdateReport, max_points: int = 1000) -> tuple[Figure, Figure]:
    """Measured vs one-step-ahead and free-run predictions, and the residuals, on the validation part.

    x: time before the end of the window (ms when the part is shorter than 2 s).
    """
    n = len(r.y_val)
    step = _decimate(n, max_points)
    y, osa, fr = (np.asarray(a, dtype=np.float64)[::step] for a in (r.y_val, r.osa_val, r.fr_val))
    band = [] if r.lower_val is None or r.upper_val is None else \
        [np.asarray(a, dtype=np.float64)[::step] for a in (r.lower_val, r.upper_val)]
    t = (r.val_t0_ns + np.arange(0, n, step, dtype=np.int64) * np.int64(r.period_ns) - r.window_end_ns) / 1e9
    lo_t = float(min(t[0], -r.period_ns / 1e9)) if t.size else -1.0
    ms = -lo_t < 2.0
    x = Axis(lo_t, 0.0, scale=1000.0 if ms else 1.0)
    unit = "ms" if ms else "s"
    m = r.metrics
    ylo, yhi = data_range([y])
    span = yhi - ylo  # predictions may leave the measured range by one span, then they are clipped
    lo, hi = data_range([y, osa, fr, *band])
    yax = Axis(max(lo, ylo - span), min(hi, yhi + span))
    when = f"window end {clock_text(r.window_end_ns)}"
    stroke = float(np.clip((CANVAS["validation"][0] - _LEFT - _RIGHT) / max(1, t.size), 1.0, 8.0))  # strokes touch
    shade = [Series("band_fill", "", COL_BAND_FILL, *_fill(t, band[0], band[1]), stroke),
             Series("band_lower", "", COL_BAND, t, band[0], 1.0),
             Series("band_upper", f"{100 * r.band_level:g} % band", COL_BAND, t, band[1], 1.0)] if band else []
    fit = figure(
        [
            *shade,  # under the lines: the free run's band (the model's prediction interval)
            Series("measured", "measured", COL_MEASURED, t, y, 2.0),
            Series("osa", f"one step ahead  R² {_r2(m.get('r2_osa_val'))}", COL_OSA, t, osa),
            Series("free_run", f"free run  R² {_r2(m.get('r2_fr_val'))}", COL_FR, t, fr),
        ],
        kind="validation", x=x, y=yax, note=f"[{r.output_name}] · {when}", x_unit=unit,
    )
    e_osa, e_fr = y - osa, y - fr
    elo, ehi = data_range([e_osa], symmetric=True)
    flo, fhi = data_range([e_fr], symmetric=True)
    lim = min(max(ehi, fhi), 4 * max(ehi, span / 2))  # a diverging free run must not flatten the OSA residual
    res = figure(
        [Series("osa", "one step ahead", COL_OSA, t, e_osa), Series("free_run", "free run", COL_FR, t, e_fr)],
        kind="residual", x=x, y=Axis(-lim, lim), note=f"measured − predicted [{r.output_name}]", zero_line=True,
        x_unit=unit,
    )
    return fit, res


def _fill(t: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The band's fill: a vertical stroke from ``lower`` to ``upper`` at each time, the strokes separated by NaN
    (the figure breaks a series at its non-finite values)."""
    n = t.shape[0]
    x, y = np.full(3 * n, np.nan), np.full(3 * n, np.nan)
    x[0::3], x[1::3] = t, t
    y[0::3], y[1::3] = lower, upper
    return x, y


def fitness_figure(newest: tuple[int, bool, np.ndarray], cold: tuple[int, np.ndarray] | None) -> Figure:
    """Best fitness per generation on a log scale: the stream's latest cold run, then the newest update.

    ``newest`` is (version, warm, fitness per generation); ``cold`` the
    (version, fitness) of the latest cold run, drawn first when the newest
    update is warm, so a warm update shows where it continues from.
    """
    version, warm, f_new = newest
    series: list[Series] = []
    marks: list[tuple[float, str]] = []
    offset = 0
    if warm and cold is not None and len(cold[1]):
        g = np.arange(1, len(cold[1]) + 1)
        series.append(Series("cold", f"cold v{cold[0]}", COL_COLD, g, cold[1], 2.0))
        offset = len(cold[1])
        marks.append((offset + 0.5, "warm"))
    g = offset + np.arange(1, len(f_new) + 1)
    label = f"{'warm' if warm else 'cold'} v{version}"
    series.append(Series("newest", label, COL_WARM if warm else COL_COLD, g, np.asarray(f_new, dtype=np.float64), 3.0))
    allf = np.concatenate([np.asarray(s.y, dtype=np.float64) for s in series])
    pos = allf[np.isfinite(allf) & (allf > 0)]
    if pos.size:
        lo, hi = float(pos.min()), float(pos.max())
        if hi / lo < 1.02:  # nearly flat: a small linear-looking range around it
            lo, hi = lo / 1.01, hi * 1.01
        yax = Axis(lo / (hi / lo) ** 0.05, hi * (hi / lo) ** 0.05, log=True)
    else:
        yax = Axis(0.1, 10.0, log=True)
    x = Axis(0.0, float(g[-1]) * 1.03 + 0.5 if len(g) else 1.5)
    return figure(series, kind="fitness", x=x, y=yax, note="MSE · log", marks_x=marks)


def plane_figure(r: UpdateReport, max_points: int = 1000) -> Figure | None:
    """The input-output plane of the validation part: measured and free-run output against the first input."""
    n = len(r.u_val)
    if n < 2 or len(r.y_val) != n:
        return None
    step = _decimate(n, max_points)
    u = np.asarray(r.u_val, dtype=np.float64)[::step]
    y = np.asarray(r.y_val, dtype=np.float64)[::step]
    fr = np.asarray(r.fr_val, dtype=np.float64)[::step]
    xlo, xhi = data_range([u])
    ylo, yhi = data_range([y])
    span = yhi - ylo
    lo, hi = data_range([y, fr])
    return figure(
        [Series("measured", "measured", COL_MEASURED, u, y, 1.2), Series("simulated", "free run", COL_FR, u, fr, 1.2)],
        kind="plane", x=Axis(xlo, xhi), y=Axis(max(lo, ylo - span), min(hi, yhi + span)),
        x_unit=r.input_name, y_title=r.output_name,
    )


def _r2(v: float | None) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{v:.4f}"
