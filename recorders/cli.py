"""``streamid record`` and ``streamid simulate`` (registered through entry points)."""

from __future__ import annotations

import argparse
import json
import sys
import threading

from streamid.errors import ConfigError
from streamid.transport import DEFAULT_ENDPOINT
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args
from streamid.commands.os_signals import stop_on_signals

__all__ = ["register_record", "register_simulate", "run_record", "run_simulate"]


def register_record(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "record",
        help="record Zenoh traffic (default streamid/**) to an MCAP log",
        description=(
            "Record every sample on the given Zenoh key expressions to a chunked, zstd-compressed "
            "MCAP file with the protobuf schema registered. SIGINT/SIGTERM finish the file; after "
            "SIGKILL every complete chunk (at most --chunk-interval old) stays readable "
            "(streamid replay --partial)."
        ),
    )
    p.add_argument("output", help="MCAP file to write; or the word convert (see below)")
    p.add_argument("convert_files", nargs="*", metavar="DATA OUT.mcap", help=argparse.SUPPRESS)
    conv = p.add_argument_group(
        "streamid record convert DATA OUT.mcap --input SIGNAL --output SIGNAL",
        "write a data file's signals as a streamid log instead of recording: an MF4/MDF file (channels by name, "
        "NAME@GROUP where a name repeats), a ROS 2 bag (directory, .mcap or .db3; /topic:field), a MATLAB .mat or "
        "a CSV; signals at their own rates are put on the output's own timestamps, the inputs zero-order held "
        "(README, 'Your lab's logs')")
    conv.add_argument("--input", action="append", dest="signal_inputs", metavar="SIGNAL",
                      help="an input signal (repeatable)")
    conv.add_argument("--output", dest="signal_output", metavar="SIGNAL", help="the output signal")
    conv.add_argument("--stream", default=None, help="stream name of the log (default: from DATA's file name)")
    conv.add_argument("--period-ms", type=float, default=None, metavar="MS",
                      help="sample period of a file without a clock (a .mat, a CSV without a time column)")
    from streamid.commands.identify_io import add_reading_flags

    add_reading_flags(conv)
    p.add_argument("--key", action="append", dest="keys", metavar="KEYEXPR",
                   help="Zenoh key expression to record (repeatable; default streamid/**)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until SIGINT/SIGTERM)")
    p.add_argument("--max-messages", type=int, default=None, metavar="N",
                   help="stop after N messages")
    p.add_argument("--chunk-interval", type=float, default=1.0, metavar="S",
                   help="close an MCAP chunk at least every S seconds (default 1.0)")
    p.add_argument("--json", action="store_true", help="print the statistics as one JSON line")
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    p.set_defaults(func=run_record)


def run_convert(args: argparse.Namespace) -> int:
    """``streamid record convert DATA OUT.mcap --input SIGNAL --output SIGNAL``."""
    from streamid.commands.identify_io import reading
    from streamid.logs.as_log import convert_to_log
    from streamid.logs.bundled import data_file

    if len(args.convert_files) == 2 and (not args.signal_inputs or not args.signal_output):
        from streamid.logs.as_log import signals_wanted

        raise signals_wanted(data_file(args.convert_files[0]), "streamid record convert takes DATA OUT.mcap --input "
                             "SIGNAL (once per input) --output SIGNAL")
    if len(args.convert_files) != 2 or not args.signal_inputs or not args.signal_output:
        raise ConfigError("streamid record convert takes DATA OUT.mcap --input SIGNAL (once per input) --output "
                          f"SIGNAL; got files {args.convert_files}, inputs {args.signal_inputs}, output "
                          f"{args.signal_output!r}")
    data, out = args.convert_files
    if not out.endswith(".mcap"):
        raise ConfigError(f"the log to write must end in .mcap; got {out!r}")
    if args.period_ms is not None and not args.period_ms > 0:
        raise ConfigError(f"--period-ms must be > 0; got {args.period_ms}")
    done = convert_to_log(data_file(data), out, args.signal_inputs, args.signal_output, stream=args.stream,
                          period_ns=None if args.period_ms is None else int(round(args.period_ms * 1e6)),
                          reading=reading(args))
    for note in done.record.notes:
        print(f"streamid record convert: warning: {note}", file=sys.stderr, flush=True)
    print(f"converted {data}: {done.samples} samples of {', '.join(args.signal_inputs)} -> {args.signal_output} "
          f"(period {done.period_ns / 1e6:.6g} ms) as stream {done.stream!r}, {done.messages} messages -> {out}",
          flush=True)
    return 0


def run_record(args: argparse.Namespace) -> int:
    from recorders.recorder import RecorderConfig, record

    if args.output == "convert":
        return run_convert(args)
    if args.convert_files or args.signal_inputs or args.signal_output or args.period_ms is not None:
        raise ConfigError("DATA OUT.mcap, --input, --output and --period-ms belong to streamid record convert DATA "
                          f"OUT.mcap ...; streamid record takes one OUTPUT file (got {args.output!r} "
                          f"{' '.join(args.convert_files)})")
    if args.max_messages is not None and args.max_messages < 1:
        raise ConfigError(f"--max-messages must be >= 1; got {args.max_messages}")
    config = RecorderConfig(
        key_exprs=tuple(args.keys or ("streamid/**",)), chunk_interval_s=args.chunk_interval,
    )
    settings = settings_from_args(args)
    stop = threading.Event()
    ready = threading.Event()
    with stop_on_signals(stop):
        stats = record(args.output, settings, config, duration_s=args.duration,
                       max_messages=args.max_messages, stop_event=stop, ready=ready)
    if args.json:
        print(json.dumps({
            "path": str(stats.path), "messages": stats.messages, "samples": stats.samples,
            "bytes": stats.bytes, "per_key": stats.per_key, "seq_gaps": stats.seq_gaps,
            "seq_out_of_order": stats.seq_out_of_order, "first_ns": stats.first_ns,
            "last_ns": stats.last_ns, "max_queue": stats.max_queue,
        }), flush=True)
    else:
        print(stats.summary(), flush=True)
    return 0


def register_simulate(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from recorders.devices import recorded_devices

    devices = recorded_devices()
    lines = "\n".join(
        f"  {d.name:<10} {d.rate_hz:>8g} Hz  {d.input_name} -> {d.output_name}  "
        f"(stream {d.stream}, {d.batch_size} samples/batch, default {d.default_seconds:g} s)"
        for d in devices.values()
    )
    p = sub.add_parser(
        "simulate",
        help="write the MCAP log of a simulated device (piezo 20 kHz, mr_damper 200 Hz, reactor 5 Hz)",
        description="Simulate a device (seeded) and write its record as a streamid MCAP log.\n\n"
                    "Devices:\n" + lines,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("device", choices=sorted(devices), help="device to simulate")
    p.add_argument("output", nargs="?", default=None, help="MCAP file to write (or -o FILE)")
    p.add_argument("-o", "--output", dest="output_opt", default=None, metavar="FILE",
                   help="MCAP file to write (instead of the positional OUTPUT)")
    p.add_argument("--duration", "--seconds", type=float, default=None, metavar="S",
                   help="record length in seconds (default: per device)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--batch-size", type=int, default=None, metavar="N",
                   help="samples per batch (default: per device)")
    p.add_argument("--stream", default=None, help="stream name (default: per device)")
    p.add_argument("--split", action="store_true",
                   help="put inputs on streamid/<s>/u and outputs on streamid/<s>/y")
    p.add_argument("--drift-at", type=float, default=None, metavar="S",
                   help="drift: from S seconds after the start, the parameters that set the output "
                        "level change (mr_damper: alpha, c0; piezo: d_p); the log's metadata records "
                        "drift_at_s, drift_at_ns and drift_change")
    p.add_argument("--drift-change", type=float, default=None, metavar="C",
                   help="relative change of those parameters with --drift-at (default 0.2 = +20 %%)")
    p.set_defaults(func=run_simulate)


def run_simulate(args: argparse.Namespace) -> int:
    from recorders.devices import simulate_device_log

    if (args.output is None) == (args.output_opt is None):
        raise ConfigError("give the MCAP file to write once: as OUTPUT or as -o FILE; got "
                          + ("neither" if args.output is None else f"both {args.output!r} and {args.output_opt!r}"))
    if args.drift_change is not None and args.drift_at is None:
        raise ConfigError(f"--drift-change needs --drift-at S (the time of the change); got --drift-change "
                          f"{args.drift_change!r} alone")
    info = simulate_device_log(
        args.device, args.output if args.output is not None else args.output_opt, seed=args.seed,
        duration_s=args.duration, batch_size=args.batch_size, stream=args.stream, split=args.split,
        drift_at_s=args.drift_at, drift_change=0.2 if args.drift_change is None else args.drift_change,
    )
    drift = (f", drift {info['drift_change']:+g} from t = {info['drift_at_ns'] / 1e9:g} s"
             if "drift_at_ns" in info else "")
    print(
        f"simulated {info['device']}: {info['samples']} samples at {1e9 / info['period_ns']:g} Hz, "
        f"{info['messages']} messages on stream {info['stream']!r}, seed {info['seed']}{drift} -> {info['path']}"
    )
    return 0
