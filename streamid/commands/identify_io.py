"""What ``streamid identify`` shows and writes around an identification: the data it reads, the progress bar, the .rrd.

Kept apart from :mod:`streamid.commands.identify` (options, runs, the report table).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TextIO

from streamid.errors import ConfigError, DataError
from streamid.logs.bundled import bundled_logs, data_file
from streamid.logs.csv_table import parse_delimiter
from streamid.logs.datafile import Dataset, load_dataset, load_table

if TYPE_CHECKING:
    from streamid.engine.search.coevolution import Progress

__all__ = ["r2_text", "Bar", "add_reading_flags", "reading", "load", "read_summary", "read_text", "split_text", "check_rrd_target", "draw_rrd", "emit_report",
           "json_safe"]


def r2_text(v: float | None, digits: int = 5, width: int = 0) -> str:
    """An R² for the reports: ``digits`` decimals, or "diverged" for a free run that left the numbers (None)."""
    return f"{'diverged' if v is None else format(v, f'.{digits}f'):>{width}}"


#: What the progress line says in an identification's stages after its search (``Progress.stage``).
STAGES = {"choice": "choosing the kept model: its size, ensemble, refinement and interval",
          "validation": "validating the kept model on the estimation and validation records"}


class Bar:
    """A one-line progress bar on a stream, redrawn at most every ``every_s``; shown after ``delay_s``
    (``streamid identify --progress auto`` waits a second, so that a quick run does not flash one)."""

    def __init__(self, stream: TextIO, enabled: bool, label: str, every_s: float = 0.05, delay_s: float = 1.0) -> None:
        self.stream, self.enabled, self.label, self.every_s, self.delay_s = stream, enabled, label, every_s, delay_s
        self.t0 = time.perf_counter()
        self.shown = False
        self._last = -1.0
        self._line = ""

    def update(self, done: float, total: float, note: str = "") -> None:
        now = time.perf_counter()
        if not self.enabled or now - self.t0 < self.delay_s or (now - self._last < self.every_s and done < total):
            return
        self._last = now
        frac = 0.0 if total <= 0 else min(1.0, done / total)
        width = 30
        bar = "#" * int(round(frac * width))
        line = f"\r{self.label} [{bar:<{width}}] {100 * frac:5.1f}% {note}   "
        if line == self._line:
            return
        self._line = line
        self.stream.write(line)
        self.stream.flush()
        self.shown = True

    def generation(self, p: Progress, run: str = "") -> None:
        """Draw one identification's progress (a generation of one of its restarts, in order; then its later
        stages: the kept model's choice, the validation)."""
        if p.stage == "search":
            self.update(p.generation, p.generations,
                        f"{run}generation {p.generation}/{p.generations}, {p.evaluations} evaluations, "
                        f"best fitness {p.best_fitness:.5g}")
        else:
            self.update(p.generation, p.generations, f"{run}{STAGES.get(p.stage, p.stage)} "
                        f"(search done: {p.evaluations} evaluations, best fitness {p.best_fitness:.5g})")

    def close(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()


def add_reading_flags(p: argparse._ActionsContainer) -> None:
    """How a data file is read, the same for every command that reads one (identify, validate): ``--delimiter``,
    ``--fill``/``--drop`` (missing values) and ``--allow-time-input``; :func:`reading` turns them into settings."""
    p.add_argument("--delimiter", metavar="D", help="CSV delimiter: , ; tab | whitespace (default: detected)")
    gaps = p.add_mutually_exclusive_group()
    gaps.add_argument("--fill", action="store_true",
                      help="fill missing values by linear interpolation between the neighbouring samples of the column")
    gaps.add_argument("--drop", action="store_true",
                      help="leave out rows with a missing value (breaks the sample spacing where they were: warned, "
                           "refused at more than one place per 100 rows)")
    p.add_argument("--allow-time-input", action="store_true",
                   help="use an input that only ever increases or decreases (a time column?) instead of refusing it")


def reading(args: argparse.Namespace) -> dict[str, Any]:
    """The reading settings of :func:`add_reading_flags`'s options: ``delimiter``, ``missing``, ``allow_time_input``."""
    return {"delimiter": parse_delimiter(args.delimiter) if args.delimiter is not None else None,
            "missing": "drop" if args.drop else "fill" if args.fill else "error",
            "allow_time_input": bool(args.allow_time_input)}


def _columns(args: argparse.Namespace, path: Path, delimiter: str | None) -> tuple[list[str], str]:
    """--input/--output, or for an MCAP log without them its stream's inputs and its only output."""
    if args.input and args.output:
        return list(args.input), args.output
    table = load_table(path, stream=args.stream, delimiter=delimiter)
    ins, outs = table.meta.get("inputs"), table.meta.get("outputs")
    if ins is None or outs is None:
        raise ConfigError(
            f"{path} is not a log that names its inputs and outputs: give --input COL (once per input) and --output "
            f"COL; its columns are {sorted(table.columns)}"
        )
    if not args.output and len(outs) != 1:
        raise ConfigError(f"stream {table.meta.get('stream')!r} of {path} has outputs {outs}: choose one with --output")
    return (list(args.input) if args.input else list(ins)), (args.output or outs[0])


def load(args: argparse.Namespace, progress: Callable[[float, float], Any] | None = None) -> Dataset:
    """The data of the command line: a file or a bundled log, the columns, delimiter, missing values, split
    (or ``--validate``'s second file); ``progress(rows_read, rows_at_most)`` while a file is read."""
    how = reading(args)
    path = data_file(args.data)
    inputs, output = _columns(args, path, how["delimiter"])
    validation = data_file(args.validate) if getattr(args, "validate", None) else None
    return load_dataset(path, inputs, output, est=args.est, est_fraction=args.est_fraction, stream=args.stream,
                        validation=validation, progress=progress, **how)


def read_text(info: dict[str, Any], period_ns: int | None, rows: int) -> str:
    """How a file was read, in one line (delimiter, decimal mark, clock, missing values), from its ``info``."""
    parts = []
    if "delimiter" in info:
        parts.append(f"{info['delimiter']}-separated, decimal {'comma' if info.get('decimal') == ',' else 'point'}")
    if period_ns:
        clock = f"clock {info['clock']!r}" if "clock" in info else "clock of the log"
        parts.append(f"{clock} (period {period_ns / 1e6:.6g} ms)")
    else:
        parts.append("no clock (samples counted)")
    m = info.get("missing", {})
    if m.get("rows_with_missing"):
        parts.append(f"{m['rows_with_missing']} rows with missing values ({m['policy']}: {m['rows_dropped']} rows left "
                     f"out, {m['values_filled']} values filled)")
    return f"{info.get('rows', rows)} rows; " + ", ".join(parts)


def read_summary(ds: Dataset) -> str:
    """How the data were read, in one line per file (the validation file's after ``; validation file: ``)."""
    text = read_text(ds.info, ds.period_ns, ds.n_est + ds.n_val)
    val = ds.info.get("validation")
    if val is not None:
        text += f"; validation file {val['path']}: " + read_text(val, ds.period_ns, ds.n_val)
    return text


def split_text(ds: Dataset) -> str:
    """Which samples are estimated on and which validated on, in words."""
    if ds.validation_path is not None:
        return f"estimation all {ds.n_est} samples of {ds.path}, validation all {ds.n_val} of {ds.validation_path}"
    return f"estimation {ds.n_est} samples (first), validation {ds.n_val} samples (rest)"


def json_safe(v: Any) -> Any:
    """``v`` with every non-finite float as None: JSON has no inf or nan, and a free run that diverged scores
    R² -inf (every report is written with ``allow_nan=False``)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    return v


def emit_report(report: dict[str, Any], *, to_stdout: bool, path: str | None) -> None:
    """A command's JSON report: one line on stdout (``--json``) and/or a file (``--report``); non-finite floats
    are written as null."""
    report = json_safe(report)
    if path:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=1, allow_nan=False)
    if to_stdout:
        print(json.dumps(report, allow_nan=False), flush=True)


def check_rrd_target(path: str) -> None:
    """Refuse an --rrd path that cannot be written, before the identification."""
    p = Path(path)
    if p.suffix != ".rrd":
        raise ConfigError(f"--rrd {path!r}: the file name must end in .rrd (e.g. --rrd result.rrd)")
    if p.is_dir():
        raise ConfigError(f"--rrd {path!r} is a directory; give a file name ending in .rrd")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise ConfigError(f"--rrd {path!r}: the directory {str(parent)!r} does not exist or cannot be written")


def draw_rrd(path: str, ds: Dataset, runs: list[dict[str, Any]], best: int, generations: int) -> list[str]:
    """Draw the kept run into ``path`` in the daemon's layout (:mod:`streamid.viz.identify_report`); the files written."""
    from streamid.model.narx import Model
    from streamid.engine.validation import validate
    from streamid.viz.identify_report import Clock, draw_identification, identify_update_report

    b = runs[best]
    model = Model.from_json(b["model"])
    rep = validate(model, ds.u_est, ds.y_est, ds.u_val, ds.y_val)
    clock = Clock.of(ds.t_ns, ds.period_ns)
    stream = Path(ds.path).stem or "data"
    events: list[tuple[str, str]] = [
        ("INFO", f"streamid identify {ds.path}: {', '.join(ds.input_names)} -> {ds.output_name}; {split_text(ds)}"
                 + (" (its times drawn after the estimation data's)" if ds.validation_path is not None else "")),
        ("INFO", f"read: {read_summary(ds)}"),
    ]
    if not clock.from_file:
        events.append(("WARN", "no time column in the file: the time axis counts one second per sample"))
    events += [("WARN", n) for n in ds.notes]
    for i, r in enumerate(runs):
        r2 = r["r2"]
        events.append(("INFO", f"run {i} (seed {r['seed']}){' kept' if i == best else ''}: R² est OSA {r2['osa_est']:.4f} "
                               f"FR {r2_text(r2['fr_est'], 4)} · val OSA {r2['osa_val']:.4f} FR {r2_text(r2['fr_val'], 4)}, "
                               f"{r['seconds']:.2f} s"))
    note = f"run {best} of {len(runs)} (seed {b['seed']}), kept by the identification's own rule on the estimation data"
    up = identify_update_report(stream, model, rep, u_val=ds.u_val, y_val=ds.y_val, n_est=ds.n_est, clock=clock,
                                fitness_history=b.get("history", []), generations=generations,
                                seconds=float(b["seconds"]), note=note)
    files = draw_identification(path, up, events)
    if not files or not Path(files[-1]).is_file():
        raise DataError(f"--rrd {path!r}: the recording could not be written (see the warning above)")
    return files


def data_help() -> str:
    """The DATA argument's help (names the bundled logs)."""
    return ("CSV/.tsv (header row), Parquet, Arrow IPC/Feather (.feather/.arrow/.ipc), MATLAB .mat (v7.3 too), "
            "streamid .mcap log, ASAM MDF .mf4/.mdf (channels by name, NAME@GROUP where a name repeats), a ROS 2 "
            "bag (directory, .mcap or .db3; signals /topic:field.path[i]), or the name of a bundled log "
            f"({', '.join(bundled_logs())})")
