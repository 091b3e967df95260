"""``streamid identify --rrd FILE`` (and ``streamid validate --rrd``): one offline result drawn in the daemon's Rerun layout.

The kept model becomes one :class:`~streamid.viz.reports.UpdateReport` (version 1,
a cold run over the whole estimation part, validated on the rest) and is drawn by
:class:`streamid.viz.rerun_view.Viz` exactly as the daemon draws an update: the
validation figure (with the free run's band when the model carries an interval), residuals, the five correlation tests, best fitness per
generation, R² (one point), the input-output plane, the model as text and an
event log (how the file was read, warnings, every run).  ``streamid view
FILE.rrd`` opens it; ``--screenshot PNG`` renders it.

Times come from the file's clock (an MCAP log, or a CSV time column such as
``time_s``); without one the time axis counts one second per sample, and the
event log says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from streamid.model.ensemble import members_of
from streamid.model.narx import Model
from streamid.engine.validation import CorrelationReport, RecordReport, ValidationReport
from streamid.viz.reports import UpdateReport, VizSettings, band_of, first_input_tests

__all__ = ["Clock", "identify_update_report", "record_update_report", "draw_identification", "NO_CLOCK_PERIOD_NS"]

#: Time axis of a file without a clock: one second per sample.
NO_CLOCK_PERIOD_NS = 1_000_000_000


@dataclass(frozen=True)
class Clock:
    """Times of the identified samples: the first sample's time and the sample period (ns)."""

    t0_ns: int
    period_ns: int
    from_file: bool

    @classmethod
    def of(cls, t_ns: NDArray[np.int64] | None, period_ns: int | None) -> Clock:
        if t_ns is not None and len(t_ns) >= 2:
            period = period_ns if period_ns and period_ns > 0 else int(np.median(np.diff(t_ns)))
            if period > 0:
                return cls(int(t_ns[0]), int(period), True)
        return cls(0, NO_CLOCK_PERIOD_NS, False)



def identify_update_report(
    stream: str,
    model: Model,
    report: ValidationReport,
    *,
    u_val: NDArray[np.float64],
    y_val: NDArray[np.float64],
    n_est: int,
    clock: Clock,
    fitness_history: Sequence[float],
    generations: int,
    seconds: float,
    note: str = "",
) -> UpdateReport:
    """The drawing of an offline identification: ``report`` must come from :func:`streamid.engine.validation.validate`."""
    return _update_report(stream, model, osa=report.predictions["osa_val"], fr=report.predictions["fr_val"],
                          correlation=report.correlation_val, r2=report.r2_dict(), u_val=u_val, y_val=y_val,
                          n_est=n_est, clock=clock, fitness_history=fitness_history, generations=generations,
                          seconds=seconds, note=note)


def record_update_report(stream: str, model: Model, report: RecordReport, *, u: NDArray[np.float64],
                         y: NDArray[np.float64], clock: Clock, note: str = "") -> UpdateReport:
    """The drawing of a model judged on a record (``streamid validate``): the whole record is the
    validation part; no estimation part and no fitness curve (no identification ran)."""
    return _update_report(stream, model, osa=report.predictions["osa"], fr=report.predictions["fr"],
                          correlation=report.correlation, r2={"osa_val": report.osa, "fr_val": report.fr}, u_val=u,
                          y_val=y, n_est=0, clock=clock, fitness_history=(), generations=0, seconds=0.0, note=note,
                          judged_only=True)


def _update_report(stream: str, model: Model, *, osa: NDArray[np.float64], fr: NDArray[np.float64],
                   correlation: CorrelationReport, r2: dict[str, float | None], u_val: NDArray[np.float64],
                   y_val: NDArray[np.float64], n_est: int, clock: Clock, fitness_history: Sequence[float],
                   generations: int, seconds: float, note: str, judged_only: bool = False) -> UpdateReport:
    n_val = len(y_val)
    n = n_est + n_val
    u = np.asarray(u_val, dtype=np.float64)
    band, figures = band_of(model, u, np.asarray(y_val, dtype=np.float64))  # the free run's band, if it has one
    metrics = {f"r2_{k}": (float("nan") if v is None else float(v)) for k, v in r2.items()}  # None: diverged
    return UpdateReport(
        stream=stream,
        version=1,
        accepted=True,
        warm=False,
        generations=generations,
        window_t0_ns=clock.t0_ns,
        window_end_ns=clock.t0_ns + n * clock.period_ns,
        period_ns=clock.period_ns,
        val_t0_ns=clock.t0_ns + n_est * clock.period_ns,
        y_val=np.asarray(y_val, dtype=np.float64),
        osa_val=np.asarray(osa, dtype=np.float64),
        fr_val=np.asarray(fr, dtype=np.float64),
        u_val=u[:, 0] if u.ndim == 2 else u,
        input_name=model.input_names[0] if model.input_names else "u",
        output_name=model.output_name,
        fitness=np.asarray(fitness_history, dtype=np.float64),
        correlations=first_input_tests(tuple(correlation.tests)),
        lags=model.lags,
        metrics={**metrics, **figures},
        identification_s=float(seconds),
        note=note,
        input_names=tuple(model.input_names),
        networks=len(members_of(model)),
        combine=getattr(model, "combine", "mean"),
        linear_parts=sum(m.linear is not None for m in members_of(model)),
        long_linear_order=model.linear_order,
        judged_only=judged_only,
        refinement=None if judged_only else model.metrics.get("refinement"),
        **band,
    )


def draw_identification(
    path: str,
    update: UpdateReport,
    events: Sequence[tuple[str, str]] = (),
    *,
    application_id: str = "streamid identify",
    layout: str = "identify",
) -> list[str]:
    """Write ``update`` (and ``events``: ``(level, text)`` pairs, before it) to the .rrd ``path``; the files written.

    One file, never rotated, its footer written on return (``rerun rrd verify`` passes).
    """
    from streamid.viz.rerun_view import Viz

    viz = Viz(VizSettings(rrd=path, rrd_rotate_mb=None, application_id=application_id, layout=layout))
    try:
        viz.add_stream(update.stream)
        for level, text in events:
            viz.log_event(update.stream, text, level=level, t_ns=update.window_t0_ns)
        viz.log_update(update)
        files = viz.files
    finally:
        viz.close(timeout_s=10.0)
    return files
