"""``streamid validate``'s work: a saved model on a record it never saw (options: :mod:`streamid.commands.validate`)."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import TextIO

import numpy as np

from streamid.commands.identify_io import check_rrd_target, emit_report, read_text, reading
from streamid.engine.choice.caveats import record_caveats
from streamid.model.narx import Model
from streamid.engine.validation import RecordReport, assess, fit_percent
from streamid.model.domain import domain_text
from streamid.model.uncertainty import interval_text
from streamid.errors import ConfigError, DataError
from streamid.threads import cores
from streamid.logs.bundled import data_file
from streamid.logs.datafile import Record, load_record, same_period

__all__ = ["model_period_ns", "validate_command"]



def model_period_ns(model: Model) -> int | None:
    """The sample period the model was identified at, from its window (None: it records none)."""
    w = model.window
    period = w.get("period_ns")
    if isinstance(period, int) and period > 0:
        return period
    t0, t1, n = w.get("t0_ns"), w.get("t1_ns"), w.get("n_samples")
    if isinstance(t0, int) and isinstance(t1, int) and isinstance(n, int) and n >= 2 and t1 > t0:
        return round((t1 - t0) / (n - 1))
    return None


def _columns(args: argparse.Namespace, model: Model) -> tuple[list[str], str]:
    inputs = list(args.input) if args.input else list(model.input_names)
    if len(inputs) != model.n_inputs:
        raise ConfigError(f"the model has {model.n_inputs} input(s) {list(model.input_names)}; --input was given "
                          f"{len(inputs)} time(s) ({inputs}): give one --input COL per model input, in its order")
    return inputs, args.output or model.output_name


def _period_notes(model: Model, rec: Record) -> list[str]:
    """Refuse a record sampled at another period than the model's; say when either has none to compare."""
    want, have = model_period_ns(model), rec.period_ns
    if want and have:
        if not same_period(want, have):
            raise DataError(f"{rec.path} samples every {have / 1e6:.6g} ms but the model was identified at one sample "
                            f"every {want / 1e6:.6g} ms: a NARX model's lags count samples, so judge it on data "
                            f"sampled at its period (resample the record)")
        return []
    if want:
        return [f"{rec.path} has no clock: its rows are taken as samples {want / 1e6:.6g} ms apart, the model's period"]
    if have:
        return [f"the model records no sample period (it was identified on a file without a clock): {rec.path}'s "
                f"{have / 1e6:.6g} ms was not checked against it"]
    return []


def _span(rec: Record, start_s: float | None, end_s: float | None,
          period_ns: int | None) -> tuple[Record, str, int]:
    """The rows of ``rec`` from ``start_s`` to ``end_s`` seconds after its first sample, how they were chosen, and
    the first one's index."""
    if start_s is None and end_s is None:
        return rec, "", 0
    _check_span(start_s, end_s)
    n = len(rec.y)
    if rec.t_ns is not None:
        t = rec.t_ns - rec.t_ns[0]
    elif period_ns:
        t = np.arange(n, dtype=np.int64) * period_ns
    else:
        raise ConfigError(f"{rec.path} has no clock and the model records no sample period: --start/--end need "
                          f"times (a time column such as time_s, or an MCAP log)")
    keep = np.ones(n, dtype=bool)
    if start_s is not None:
        keep &= t >= round(start_s * 1e9)
    if end_s is not None:
        keep &= t <= round(end_s * 1e9)
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        raise DataError(f"{rec.path} has no sample between --start and --end: it spans {t[-1] / 1e9:.6g} s")
    a, b = int(rows[0]), int(rows[-1]) + 1
    part = replace(rec, u=rec.u[a:b], y=rec.y[a:b], t_ns=None if rec.t_ns is None else rec.t_ns[a:b])
    return part, _span_text(a, b, int(t[a]), int(t[b - 1]), n), a


def _check_span(start_s: float | None, end_s: float | None) -> None:
    for flag, v in (("--start", start_s), ("--end", end_s)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ConfigError(f"{flag} must be a number of seconds >= 0 after the record's first sample; got {v}")
    if start_s is not None and end_s is not None and not end_s > start_s:
        raise ConfigError(f"--end must be later than --start; got --start {start_s:g} --end {end_s:g}")


def _span_text(a: int, b: int, t_a: int, t_b: int, n: int) -> str:
    """How the rows ``a..b-1`` of ``n`` were chosen by --start/--end (``t_a``, ``t_b``: the first and last one's
    time after the record's first sample, ns)."""
    return f"rows {a}..{b - 1} ({t_a / 1e9:.6g}-{t_b / 1e9:.6g} s) of {n}"


def _streamed(args: argparse.Namespace, model: Model, inputs: list[str], output: str,
              path: Path) -> tuple[Record, RecordReport, list[str], list[str], str] | None:
    """The report read and made a piece at a time (:mod:`streamid.logs.pieces`, :mod:`streamid.engine.streamed`):
    memory bounded by the piece, for a CSV, Parquet or Arrow file longer than one chunk; None for any other (or
    one that reader does not read as the whole-file reader does), which is then read whole."""
    from streamid.engine.choice.caveats import summed_record_caveats
    from streamid.engine.streamed import StreamedRecord
    from streamid.logs.pieces import LongRun, NotStreamable, PieceReader

    how = reading(args)
    try:
        reader = PieceReader(str(path), inputs, output, how["delimiter"], how["missing"])
    except NotStreamable:
        return None
    span = args.start is not None or args.end is not None
    if span:
        _check_span(args.start, args.end)
    if span and reader.assumed is None and not model_period_ns(model):
        return None  # no times: the whole-file path says so
    lo = -1 if args.start is None else round(args.start * 1e9)
    hi = None if args.end is None else round(args.end * 1e9)
    acc = StreamedRecord(model, threads=cores())
    row, t0, first, last = 0, 0, -1, -1
    t_first = t_last = 0
    try:
        for u, y, t in reader.pieces():
            k = y.shape[0]
            if span:
                if t is not None:
                    t0 = int(t[0]) if row == 0 else t0
                    tt = t - t0
                else:
                    tt = np.arange(row, row + k, dtype=np.int64) * int(model_period_ns(model) or 0)
                kept = np.flatnonzero((tt >= lo) & (tt <= (tt[-1] if hi is None else hi)))
                if kept.size:
                    i, j = int(kept[0]), int(kept[-1]) + 1
                    first, t_first = (row + i, int(tt[i])) if first < 0 else (first, t_first)
                    last, t_last = row + j - 1, int(tt[j - 1])
                    acc.feed(u[i:j], y[i:j])
            else:
                acc.feed(u, y)
            row += k
        notes_r, info, period_ns, clock = reader.finish(how["allow_time_input"])
    except LongRun as exc:
        print(f"streamid validate: reading {path} whole (its memory grows with the record): {exc}", file=sys.stderr,
              flush=True)
        return None
    except NotStreamable:
        return None
    if not acc.started or (span and clock != reader.assumed):
        return None  # one chunk or less (assess's own path, to the bit), or times that were not the clock's
    rec = Record(str(path), tuple(inputs), output, np.empty((0, len(inputs))), np.empty(0), None, tuple(notes_r),
                 info, period_ns)
    for note in rec.notes:
        print(f"streamid validate: warning: {note}", file=sys.stderr, flush=True)
    notes = _period_notes(model, rec)
    a = max(first, 0) if span else 0
    text = _span_text(a, last + 1, t_first, t_last, row) if span else ""
    notes += _seen_notes(model, rec.path, a, acc.buffered + acc.a)
    acc.finish()
    rep = acc.report()
    caveats = summed_record_caveats(model, rep.osa, rep.fr, acc.ranges(), rep.n, acc.arx.radius(),
                                    rep.fr_diverged_at)
    return rec, rep, notes, caveats, text


def _seen_notes(model: Model, path: str, first: int, n: int) -> list[str]:
    """Say so when the rows judged include some of those the model was fitted on (a model from ``streamid
    identify`` records its file's name and the rows of its estimation data)."""
    w = model.window
    start, stop = w.get("start"), w.get("stop")
    if w.get("source") != Path(path).name or not isinstance(start, int) or not isinstance(stop, int):
        return []
    lo, hi = max(start, first), min(stop, first + n)
    if hi <= lo:
        return []
    return [f"{hi - lo} of the samples judged are ones the model was fitted on (rows {lo}..{hi - 1} of "
            f"{w['source']}): these figures are not all on data it never saw (--start past them)"]


def _model_text(model: Model) -> str:
    w = model.window
    where = f"identified on {w['source']}" if w.get("source") else (
        f"identified on window {w['number']} of its stream" if "number" in w else "identified")
    n = w.get("n_samples")
    period = model_period_ns(model)
    return (f"{model.output_name}(t) = F[{model.lags_text()}], {model.neurons} neurons; {where}"
            + (f" ({n} samples" + (f", one every {period / 1e6:.6g} ms" if period else "") + ")" if n else ""))


def _print(out: TextIO, args: argparse.Namespace, model: Model, rec: Record, rep: RecordReport, notes: list[str],
           caveats: list[str], span: str) -> None:
    w = out.write
    w(f"streamid validate: {args.model} on {rec.path}\n")
    w(f"  model     {_model_text(model)}\n")
    w(f"  read      {read_text(rec.info, rec.period_ns, rep.n)}\n")
    mapped = [f"{c} as {m}" for c, m in zip([*rec.input_names, rec.output_name], [*model.input_names, model.output_name])
              if c != m]
    w(f"  data      {rep.n} samples of {', '.join(rec.input_names)} -> {rec.output_name}"
      + (f" ({', '.join(mapped)})" if mapped else "") + (f", {span}" if span else "")
      + f"; R² over the {rep.n_scored} after the first {model.max_lag}, which start the predictions\n\n")
    w(f"  {'':16} {'R²':>9} {'fit %':>8} {'RMSE':>11}\n")
    for name, r2v, rmse in (("free run", rep.fr, rep.rmse_fr), ("one step ahead", rep.osa, rep.rmse_osa)):
        if r2v is None or rmse is None:  # a diverged free run: no R² (the caveat names the sample)
            w(f"  {name:16} {'diverged':>9} {'-':>8} {'-':>11}\n")
            continue
        w(f"  {name:16} {r2v:>9.5f} {fit_percent(r2v):>8.2f} {rmse:>11.5g}\n")
    w(interval_text(rep.interval, "record") + "\n")
    w(domain_text(rep.outside_domain, "record") + "\n")
    for n in notes:
        w(f"note: {n}\n")
    for c in caveats:
        w(f"caveat: {c}\n")
    tests = rep.correlation
    w(f"correlation tests on the one-step residual ({tests.n} samples, 95 % band ±{tests.band:.3g}):\n")
    for t in tests.tests:
        w(f"  {t.verdict()}\n")


def _draw(path: str, model: Model, rec: Record, rep: RecordReport, notes: list[str], caveats: list[str]) -> list[str]:
    from streamid.viz.identify_report import Clock, draw_identification, record_update_report

    clock = Clock.of(rec.t_ns, rec.period_ns or model_period_ns(model))
    events = [("INFO", f"streamid validate: the model {model.output_name}(t) = F[{model.lags_text()}] judged on "
                       f"{rec.path}, {rep.n} samples (no identification ran)"),
              ("INFO", f"read: {read_text(rec.info, rec.period_ns, len(rec.y))}")]
    events += [("WARN", n) for n in [*rec.notes, *notes, *caveats]]
    up = record_update_report(Path(rec.path).stem or "data", model, rep, u=rec.u, y=rec.y, clock=clock,
                              note=f"{rep.n} samples")
    files = draw_identification(path, up, events, application_id="streamid validate", layout="validate")
    if not files or not Path(files[-1]).is_file():
        raise DataError(f"--rrd {path!r}: the recording could not be written (see the warning above)")
    return files


def _whole(args: argparse.Namespace, model: Model, inputs: list[str],
           output: str) -> tuple[Record, RecordReport, list[str], list[str], str]:
    """The report on the record read whole (any format; a record of one chunk or less; with --rrd)."""
    try:
        rec = load_record(data_file(args.data), inputs, output, stream=args.stream, **reading(args))
    except DataError as exc:
        unknown = ("unknown column", "no channel", "no topic")  # (a table's, an MDF file's, a ROS 2 bag's)
        if args.input and args.output or not any(u in str(exc) for u in unknown):
            raise
        raise DataError(f"{exc}; the columns default to the model's signal names ({', '.join(model.input_names)} -> "
                        f"{model.output_name}): map the record's own with --input COL (once per model input, in its "
                        f"order) and --output COL") from None
    for note in rec.notes:
        print(f"streamid validate: warning: {note}", file=sys.stderr, flush=True)
    notes = _period_notes(model, rec)
    rec, span, first = _span(rec, args.start, args.end, rec.period_ns or model_period_ns(model))
    notes += _seen_notes(model, rec.path, first, len(rec.y))
    if len(rec.y) < model.max_lag + 2 + 20:
        raise DataError(f"{rec.path} has {len(rec.y)} samples; judging a model of max lag {model.max_lag} needs at "
                        f"least {model.max_lag + 22} (its first {model.max_lag} start the predictions)")
    # this command's cores (the same report, sooner); the full-length predictions only for the drawing
    rep = assess(model, rec.u, rec.y, threads=cores(), keep=args.rrd is not None)
    caveats = record_caveats(model, rep.osa, rep.fr, rec.u, rec.y, rep.fr_diverged_at)
    return rec, rep, notes, caveats, span


def validate_command(args: argparse.Namespace) -> int:
    """``streamid validate``'s work, with its options ``args``; the exit status."""
    if args.rrd is not None:
        check_rrd_target(args.rrd)
    if args.min_r2_fr is not None and not (math.isfinite(args.min_r2_fr) and args.min_r2_fr <= 1.0):
        raise ConfigError(f"--min-r2-fr must be a finite number <= 1 (an R²); got {args.min_r2_fr}")
    model = Model.load(args.model)
    inputs, output = _columns(args, model)
    streamed = None if args.rrd is not None else _streamed(args, model, inputs, output, data_file(args.data))
    if streamed is not None:  # a long CSV, Parquet or Arrow file, read and judged a piece at a time
        rec, rep, notes, caveats, span = streamed
    else:
        rec, rep, notes, caveats, span = _whole(args, model, inputs, output)
    passed = None if args.min_r2_fr is None else bool(rep.fr is not None and rep.fr >= args.min_r2_fr)
    files = _draw(args.rrd, model, rec, rep, notes, caveats) if args.rrd is not None else []
    if not args.json:
        _print(sys.stdout, args, model, rec, rep, notes, caveats, span)
        if files:
            print(f"rrd: {', '.join(files)} (streamid view {args.rrd}; --screenshot PNG renders it)")
        if passed is not None:
            print(f"{'passed' if passed else 'FAILED'}: free-run R² "
                  f"{'diverged' if rep.fr is None else format(rep.fr, '.5f')} "
                  f"{'>=' if passed else '<'} --min-r2-fr {args.min_r2_fr:g}")
    if args.json or args.report:
        report = {
            "format": "streamid.validate_report/1",
            "model": {"path": args.model, "inputs": list(model.input_names), "output": model.output_name,
                      "lags": model.lags, "neurons": model.neurons, "max_lag": model.max_lag,
                      "period_ns": model_period_ns(model), "window": model.window},
            "data": {"path": rec.path, "inputs": list(rec.input_names), "output": rec.output_name, "n": rep.n,
                     "start_s": args.start, "end_s": args.end, "span": span or None,
                     "period_ns": rec.period_ns, "read": rec.info, "warnings": list(rec.notes)},
            **rep.to_dict(),
            "notes": notes,
            "caveats": caveats,
            "min_r2_fr": args.min_r2_fr,
            "passed": passed,
            "rrd": files,
        }
        emit_report(report, to_stdout=args.json, path=args.report)
    return 1 if passed is False else 0

