"""``streamid daemon``: identify streams online, publish models, draw diagnostics.

Subscribes to ``streamid/<stream>/samples`` (or the separate ``u`` and ``y``
keys, aligned by time), re-identifies every stream on its newest window --
cold first, then warm-started from the previous populations -- and publishes
each model on ``streamid/<stream>/model`` (also answering queries there) and
counters on ``streamid/<stream>/status``.  Runs with embedded defaults when no
``--config`` is given (10 s windows updated every second, discovery of every
stream).  SIGINT/SIGTERM stop it within 2 s, writing the ``.rrd`` footer and the
state.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from typing import Any

from streamid.errors import ConfigError

DEFAULT_RRD = "streamid.rrd"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from streamid.transport import DEFAULT_ENDPOINT
    from streamid.commands.zenoh_flags import add_connection_flags

    p = sub.add_parser(
        "daemon",
        help="identify streams online over Zenoh; publish models; draw diagnostics in Rerun",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", metavar="FILE.toml", help="daemon configuration (TOML); default: embedded defaults")
    p.add_argument("--stream", action="append", metavar="NAME",
                   help="serve only this stream (repeatable); default: configured streams or discovery")
    add_connection_flags(p, default_listen=(DEFAULT_ENDPOINT,))
    sinks = p.add_argument_group("rerun diagnostics")
    sinks.add_argument("--rrd", metavar="PATH",
                       help=f"write diagnostics to this .rrd file (default {DEFAULT_RRD} when no other sink is given)")
    sinks.add_argument("--rerun-connect", metavar="URL",
                       help="stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    sinks.add_argument("--rerun-serve", metavar="PORT", type=int,
                       help="serve diagnostics on 127.0.0.1:PORT for viewers to connect to")
    sinks.add_argument("--rrd-rotate-mb", type=float, default=64.0, metavar="MB",
                       help="continue the .rrd in PATH.001.rrd, ... past this size or --rrd-rotate-s, keeping the newest "
                            "4096 files, 1024 MB (default 64; 0 = one file, never rotated; see streamid view)")
    sinks.add_argument("--rrd-rotate-s", type=float, default=5.0, metavar="S", help="... and every S seconds, so a "
                       "SIGKILL leaves at most S s without footer (default 5; 0 = by size only)")
    sinks.add_argument("--no-rerun", action="store_true", help="no diagnostics at all")
    p.add_argument("--state-dir", metavar="DIR",
                   help="save models and populations here; resume warm from them (also keeps the daemon's id, "
                        "so a restart is recognised by subscribers; a damaged file is quarantined and its version "
                        "recovered; on a full disk models are still published)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until signalled)")
    p.add_argument("--print-config", action="store_true", help="print every effective setting as TOML that --config reads back, and exit")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v info, -vv debug)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from streamid.daemon.config import load_config, to_toml
    from streamid.daemon.service import Daemon
    from streamid.commands.zenoh_flags import settings_from_args

    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    config = load_config(args.config)
    if args.stream:
        config = config.with_streams(tuple(args.stream))
    if args.print_config:
        print(to_toml(config), end="")
        return 0
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be a number of seconds > 0; got {args.duration}")
    zenoh = settings_from_args(args)
    viz = _viz(args)
    stop = threading.Event()
    daemon = Daemon(config, zenoh, viz=viz, state_dir=args.state_dir)

    def _on_signal(signum: int, _frame: Any) -> None:
        stop.set()
        daemon.request_stop()  # also ends a wait for the router at start

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            daemon.start()
        except BaseException:
            if viz is not None:
                viz.close()
            raise
        where = ", ".join(zenoh.listen or zenoh.connect) or "zenoh config"
        origin = daemon.versions.origin
        print(f"streamid daemon: serving on {where} as daemon {origin.daemon} (epoch {origin.epoch_ns}); "
              "Ctrl-C to stop", file=sys.stderr, flush=True)
        end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.wait(0.1):
            if end is not None and time.monotonic() >= end:
                break
    finally:
        t0 = time.monotonic()
        daemon.stop(timeout_s=2.0)
        for s, h in old.items():
            signal.signal(s, h)
    print(f"streamid daemon: stopped in {time.monotonic() - t0:.2f} s", file=sys.stderr, flush=True)
    return 0


def _viz(args: argparse.Namespace) -> Any:
    if args.no_rerun:
        if args.rrd or args.rerun_connect or args.rerun_serve:
            raise ConfigError("--no-rerun excludes --rrd, --rerun-connect and --rerun-serve; give one or the other")
        return None
    from streamid.viz.rerun_view import Viz, VizSettings

    rrd = args.rrd
    if rrd is None and args.rerun_connect is None and args.rerun_serve is None:
        rrd = DEFAULT_RRD
    if not args.rrd_rotate_mb >= 0:
        raise ConfigError(f"--rrd-rotate-mb must be a size in MB >= 0 (0 = never rotate); got {args.rrd_rotate_mb}")
    return Viz(VizSettings(rrd=rrd, connect=args.rerun_connect, serve_port=args.rerun_serve,
                           rrd_rotate_mb=args.rrd_rotate_mb or None, rrd_rotate_s=args.rrd_rotate_s or None))
