"""``streamid replay`` (registered through an entry point)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from streamid.errors import ConfigError, LogError
from streamid.logs import bundled_log, bundled_logs
from streamid.transport import DEFAULT_ENDPOINT
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args
from streamid.commands.os_signals import stop_on_signals

if TYPE_CHECKING:
    from replay.player import ReplayConfig

__all__ = ["register", "run", "resolve_log"]


def resolve_log(name: str) -> Path:
    """A path, or the name of a bundled log (``mr_damper``, ``piezo_p885``).

    Raises
    ------
    LogError
        If ``name`` is neither an existing file nor a bundled log; the message lists the
        bundled logs and the closest match.
    """
    path = Path(name)
    if path.exists():
        return path
    stem = name[:-5] if name.endswith(".mcap") else name
    if "/" in name or "\\" in name:
        raise LogError(f"LOG must be an existing MCAP file or a bundled log name ({', '.join(bundled_logs())}); no file {name!r}")
    try:
        return bundled_log(stem)
    except LogError as exc:
        raise LogError(f"no file {name!r} here, and {exc}") from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "replay",
        help="play an MCAP log onto Zenoh with its original timing (scaled) or at full speed",
        description=(
            "Play a streamid MCAP log onto Zenoh. The bytes put on Zenoh are the logged bytes "
            "(byte-exact), except with --stream (the batch's stream name is rewritten) and on "
            "the 2nd+ pass of --loop (sequence numbers and times continue forward). LOG is a "
            f"file or a bundled log name ({', '.join(bundled_logs()) or 'none'})."
        ),
    )
    p.add_argument("log", help="MCAP log file or bundled log name")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--rate", type=float, default=1.0,
                       help="time scale, 1.0 = real time (default), 2.0 = twice as fast")
    speed.add_argument("--max-speed", action="store_true", help="put messages back to back")
    p.add_argument("--loop", type=int, nargs="?", const=0, default=1, metavar="N",
                   help="play N passes (default 1); --loop alone repeats until SIGINT/SIGTERM")
    p.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="skip the first S seconds of the log")
    p.add_argument("--end", type=float, default=None, metavar="S",
                   help="stop S seconds after the log's start")
    p.add_argument("--stream", action="append", metavar="NEW|OLD=NEW",
                   help="publish under another stream name (repeatable as OLD=NEW)")
    p.add_argument("--key", action="append", dest="keys", metavar="KEY",
                   help="replay only this logged key (repeatable)")
    p.add_argument("--wait-subscribers", type=float, default=5.0, metavar="S",
                   help="wait up to S seconds for a subscriber before starting (default 5)")
    p.add_argument("--partial", action="store_true",
                   help="replay every complete chunk of a truncated/corrupt log")
    p.add_argument("--require-subscriber", action="store_true",
                   help="exit with code 1 when no subscriber received the messages (default: say so and exit 0)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON line on stdout")
    lab = p.add_argument_group(
        "a data file instead of a log",
        "LOG may be an MF4/MDF file, a ROS 2 bag (directory, .mcap or .db3), a MATLAB .mat or a CSV: its signals "
        "--input ... --output ... are read as streamid identify reads them (other rates put on the output's own "
        "timestamps, inputs zero-order held), played as one stream (named by --stream NEW, default the file's "
        "name) at their recorded times")
    lab.add_argument("--input", action="append", dest="signal_inputs", metavar="SIGNAL",
                     help="an input signal of the data file (repeatable)")
    lab.add_argument("--output", dest="signal_output", metavar="SIGNAL", help="the output signal of the data file")
    lab.add_argument("--period-ms", type=float, default=None, metavar="MS",
                     help="sample period of a data file without a clock")
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    p.set_defaults(func=run)


def _as_log(args: argparse.Namespace, path: Path, tmp: Path, config: ReplayConfig) -> tuple[Path, ReplayConfig]:
    """A streamid log as it is; a data file (MF4, ROS 2 bag, .mat, CSV) converted into ``tmp`` first."""
    from streamid.logs.as_log import convert_to_log, is_streamid_log

    if is_streamid_log(path):
        if args.signal_inputs or args.signal_output:
            raise ConfigError(f"{path} is a streamid log: it is played as it is; --input/--output choose the signals "
                              "of a data file (MF4, ROS 2 bag, .mat, CSV)")
        return path, config
    if not args.signal_inputs or not args.signal_output:
        from streamid.logs.as_log import signals_wanted

        raise signals_wanted(path, f"{path} is a data file, not a streamid log: name the signals to play, --input "
                             "SIGNAL (once per input) --output SIGNAL, as streamid identify takes them")
    stream = None
    if config.stream_map:
        if len(config.stream_map) != 1 or config.stream_map[0][0] != "*":
            raise ConfigError("a data file is played as one stream: give its name as --stream NEW (not OLD=NEW)")
        stream = config.stream_map[0][1]
    done = convert_to_log(path, tmp / "converted.mcap", args.signal_inputs, args.signal_output, stream=stream,
                          period_ns=None if args.period_ms is None else int(round(args.period_ms * 1e6)))
    for note in done.record.notes:
        print(f"streamid replay: warning: {note}", file=sys.stderr, flush=True)
    print(f"streamid replay: {path}: {done.samples} samples of {', '.join(args.signal_inputs)} -> "
          f"{args.signal_output} as stream {done.stream!r}", file=sys.stderr, flush=True)
    return done.path, dataclasses.replace(config, stream_map=())


def run(args: argparse.Namespace) -> int:
    from replay.player import ReplayConfig, parse_stream_map, replay_log

    if args.rate is not None and not args.rate > 0:
        raise ConfigError(f"--rate must be > 0 (1.0 = real time); got {args.rate}")
    config = ReplayConfig(
        rate=args.rate, max_speed=args.max_speed, loops=args.loop, start_s=args.start,
        end_s=args.end, stream_map=parse_stream_map(args.stream),
        keys=tuple(args.keys) if args.keys else None,
        wait_subscribers_s=args.wait_subscribers, partial=args.partial,
    )
    path = resolve_log(args.log)
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="streamid-replay-") as tmp:
        path, config = _as_log(args, path, Path(tmp), config)
        with stop_on_signals(stop):
            report = replay_log(path, settings_from_args(args), config, stop_event=stop)
    if args.json:
        print(json.dumps({
            "path": str(report.path), "messages": report.messages, "samples": report.samples,
            "bytes": report.bytes, "passes": report.passes, "wall_s": report.wall_s,
            "samples_per_s": report.samples_per_s, "per_key": report.per_key,
            "timing_error_us": report.timing_error_us(), "problem": report.problem,
            "unheard_keys": report.unheard_keys,
        }), flush=True)
    else:
        print(report.summary(), flush=True)
    if report.unheard_keys and args.require_subscriber:
        return 1
    return 0
