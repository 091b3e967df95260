"""``streamid watch``: print model updates live (version, lags, R^2, age).

Connects to the daemon (``tcp/127.0.0.1:7447`` by default), prints the current
model of every watched stream at once (from the daemon's queryable), then one
line per new model; with ``--every S`` the age of the current models is
re-printed every S seconds, and degraded streams are reported from their
status.  Stops on Ctrl-C, after ``--count`` updates or after ``--duration``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from typing import Any

from streamid.errors import ConfigError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from streamid.transport import DEFAULT_ENDPOINT
    from streamid.commands.zenoh_flags import add_connection_flags

    p = sub.add_parser(
        "watch",
        help="print identified models live (version, lags, R^2, age)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--stream", default="*", metavar="NAME", help="stream to watch (default: every stream)")
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    p.add_argument("--every", type=float, default=0.0, metavar="S",
                   help="also re-print the current models' age every S seconds (default: off)")
    p.add_argument("--count", type=int, metavar="N", help="exit after N model updates")
    p.add_argument("--duration", type=float, metavar="S",
                   help="exit after S seconds (with code 1 if no model was received by then)")
    p.add_argument("--json", action="store_true", help="print each update as one JSON line")
    p.set_defaults(func=run)


def format_update(up: Any, now_ns: int | None = None) -> str:
    """One line: stream, version, lags, validation R^2, age."""
    now_ns = time.time_ns() if now_ns is None else now_ns
    m = up.metrics
    age = max(0.0, (now_ns - up.published_unix_ns) / 1e9) if up.published_unix_ns else float("nan")

    def f(v: Any) -> str:
        return f"{v:.4f}" if isinstance(v, (int, float)) else "n/a"

    return (
        f"{up.stream} v{up.version} {'warm' if up.warm else 'cold'} G={up.generations} "
        f"{up.model.output_name}(t) = F[{up.model.lags_text()}] R2 val OSA {f(m.get('r2_osa_val'))} FR {f(m.get('r2_fr_val'))} "
        f"ident {up.identification_s:.2f}s age {age:.1f}s"
    )


def run(args: argparse.Namespace) -> int:
    from streamid.transport.client import ModelSubscriber
    from streamid.wire.documents import parse_status
    from streamid.errors import ModelFormatError
    from streamid.wire.keys import PREFIX, status_key
    from streamid.transport import Bus
    from streamid.commands.zenoh_flags import settings_from_args

    if args.count is not None and args.count < 1:
        raise ConfigError(f"--count must be an integer >= 1; got {args.count}")
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be a number of seconds > 0; got {args.duration}")
    if not args.every >= 0:
        raise ConfigError(f"--every must be a number of seconds >= 0; got {args.every}")
    stop = threading.Event()
    seen = [0]
    degraded: dict[str, bool] = {}
    out_lock = threading.Lock()

    def emit(text: str) -> None:
        with out_lock:
            print(text, flush=True)

    def on_update(up: Any) -> None:
        emit(json.dumps(up.document) if args.json else format_update(up))
        seen[0] += 1
        if args.count is not None and seen[0] >= args.count:
            stop.set()

    def on_status(key: str, payload: bytes) -> None:
        try:
            st = parse_status(payload)
        except ModelFormatError:
            return
        name, bad = st.get("stream", key), bool(st.get("degraded"))
        prev = degraded.get(name)
        degraded[name] = bad
        if bad and prev is not True:
            emit(f"{name} DEGRADED: {st.get('degraded_reason', '')}")
        elif not bad and prev is True:
            emit(f"{name} healthy again (model v{st.get('version')})")

    settings = settings_from_args(args)
    where = ", ".join(settings.connect) or ", ".join(f"listening on {e}" for e in settings.listen) or "the --zenoh-config endpoints"
    timed_out = False
    end = None if args.duration is None else time.monotonic() + args.duration
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with Bus(settings) as bus:
            wait = 5.0 if args.duration is None else min(5.0, args.duration)
            if not bus.wait_connected(wait):
                print(f"streamid watch: nothing reachable at {where} yet (no daemon or router there); still trying",
                      file=sys.stderr, flush=True)
            skey = f"{PREFIX}/*/status" if args.stream == "*" else status_key(args.stream)
            bus.subscribe(skey, on_status)
            with ModelSubscriber(bus, args.stream, on_update) as sub:
                if not sub.latest:
                    print(f"streamid watch: waiting for models on {args.stream!r} ...", file=sys.stderr, flush=True)
                next_age = time.monotonic() + args.every if args.every else None
                while not stop.wait(0.1):
                    now = time.monotonic()
                    if end is not None and now >= end:
                        timed_out = True
                        break
                    if next_age is not None and now >= next_age:
                        next_age = now + args.every
                        for up in list(sub.latest.values()):
                            emit(format_update(up))
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if timed_out and seen[0] == 0:
        print(f"streamid watch: no model received from {where} in {args.duration:g} s", file=sys.stderr, flush=True)
        return 1
    return 0
