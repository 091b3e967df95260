"""``streamid record`` and ``streamid simulate`` (registered through entry points)."""

from __future__ import annotations

import argparse
import json
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
    p.add_argument("output", help="MCAP file to write")
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


def run_record(args: argparse.Namespace) -> int:
    from recorders.recorder import RecorderConfig, record

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
