"""``streamid watch``: print model updates live (version, lags, R^2, age, interval, why accepted).

Connects to the daemon (``tcp/127.0.0.1:7447`` by default), prints the current
model of every output of every watched stream at once (from the daemon's
queryable), then one line per new model with its prediction interval (the 90 % free-run band
"FR -+ q x (scale + spread)" and the calibration's held-out R2; on held-out data, when the update says, how much
of it the band covered and the share outside the model's estimation domain) and why it was accepted ("accepted:
better than v12 (FR R2 0.9370 on the same data) by 0.013"); with ``--rejected`` also the challengers that were
not; with ``--every S`` the age of the current models is re-printed every S
seconds.  From the streams' status it also says when a stream becomes degraded or healthy again, and when
an output's served model no longer fits the incoming data (a drift: the next identification then starts from the
change); with ``--json`` these are JSON lines too (``"format": "streamid.status-event/1"``,
:mod:`streamid.wire.status_events`).  With ``--save-fmu DIR`` each newly served champion is also written as an
FMI 2.0 co-simulation FMU (``streamid export``'s), ``DIR/<stream>+v<version>.fmu``, and the newest as
``DIR/<stream>.fmu``, each replaced whole, for a simulation rig to pick up; within bounds: ``--keep`` versions a
stream, ``--max-bytes`` in the folder, ``--max-pending`` models waiting (the oldest dropped, said), one compile at
a time with a time budget from the model's size (:mod:`streamid.export.saver`).  Stops on Ctrl-C, SIGTERM,
after ``--count`` updates or after ``--duration`` (within a second, a compile under way killed).  Names and reasons that came
from the network are shown escaped (control, format and bidi characters as \\uXXXX).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import signal
import sys
import threading
import time
from typing import Any

from streamid.errors import ConfigError
from streamid.wire.names import printable


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from streamid.transport import DEFAULT_ENDPOINT
    from streamid.commands.zenoh_flags import add_connection_flags

    p = sub.add_parser(
        "watch",
        help="print identified models live (version, lags, R^2, interval, age)",
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
    p.add_argument("--rejected", action="store_true",
                   help="also print the rejected challengers (streamid/<stream>/rejected) and why")
    p.add_argument("--json", action="store_true",
                   help="print each update, and each status event (drift, degraded, healthy), as one JSON line")
    p.add_argument("--save-fmu", metavar="DIR",
                   help="write each newly served champion as DIR/<stream>+v<version>.fmu (an FMI 2.0 co-simulation "
                        "FMU of the stream's current model of every output, streamid export's) and the newest also as "
                        "DIR/<stream>.fmu, each file replaced whole, for a simulation rig to pick up")
    p.add_argument("--keep", type=int, default=3, metavar="N",
                   help="--save-fmu: versioned FMUs kept per stream, the oldest deleted (default 3; 0: only the newest)")
    p.add_argument("--max-bytes", type=int, default=256 * 2**20, metavar="B",
                   help="--save-fmu: bytes the folder's FMUs may hold, the oldest versions deleted first (default 256 MiB)")
    p.add_argument("--max-pending", type=int, default=4, metavar="N",
                   help="--save-fmu: models waiting to be compiled; beyond, the oldest is dropped and said (default 4)")
    p.set_defaults(func=run)


def _r2(v: Any) -> str:
    return f"{v:.4f}" if isinstance(v, (int, float)) and not isinstance(v, bool) else "n/a"


def decision_text(up: Any) -> str:
    """Why ``up`` was accepted or rejected, in a few words ("" when its daemon did not say); not escaped."""
    d = getattr(up, "decision", None)
    if d is None:
        return ""
    word = "accepted" if d.accepted else "rejected"
    c = d.champion
    fr = up.metrics.get("r2_fr_val")
    by = None
    if c is not None and isinstance(fr, float) and c.r2_fr_val is not None:
        by = fr - c.r2_fr_val
    if d.code == "first":
        return f"{word}: first model"
    # the champion's figure is on the challenger's held-out data, not the one its own line showed: say so
    same = f" (FR R2 {c.r2_fr_val:.4f} on the same data)" if c is not None and c.r2_fr_val is not None else ""
    if c is not None and d.code == "better":
        return f"{word}: better than v{c.version}{same}" + (f" by {by:.3f}" if by is not None else "")
    if c is not None and d.code == "not_better":
        margin = f", margin {d.margin:g}" if d.margin is not None else ""
        return f"{word}: not better than v{c.version}{same}" + (f": {by:+.3f}{margin}" if by is not None else "")
    if c is not None and d.code == "champion_invalid":
        return f"{word}: champion v{c.version} no longer valid on current data, FR R2 {_r2(c.r2_fr_val)} -> {_r2(fr)}"
    reason = d.reason if len(d.reason) <= 200 else d.reason[:197] + "..."
    return f"{word} ({d.code}): {reason}"


def _how(up: Any) -> str:
    """How the model was made: ``warm G=30`` / ``cold G=400`` (a coevolution run; ``refined (held out FR a -> b)``
    when its weights were then fitted to its free run: the held-out half's R^2 that let it), ``refreshed from v3``
    (the champion's weights re-solved on new data, its structure kept: streamid.online.refresh)."""
    doc = getattr(up, "document", None) or {}
    if doc.get("update") == "refreshed":
        src = doc.get("refreshed_from")
        return f"refreshed from v{src}" if isinstance(src, int) and not isinstance(src, bool) else "refreshed"
    from streamid.viz.reports import held_out_gain

    gain = held_out_gain(up.model.metrics.get("refinement"))  # its weights fitted to its free run (engine.refine)
    run = f"{'warm' if up.warm else 'cold'} G={up.generations}"
    return run if gain is None else f"{run} refined (held out FR {gain})"


def _share(v: Any) -> float | None:
    """``v`` when it is a share (a real number in [0, 1]); None for anything else a publisher may have sent."""
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0
    return float(v) if ok else None


def interval_part(up: Any) -> str:
    """What ``up``'s model says of its uncertainty, in a few words: its free-run band (level, quantile and scale:
    ``FR -+ q x (scale + spread)``, the calibration's held-out FR R^2 from ``metrics.calibration``) or why it has
    none, then, when the update's metrics carry them, the band's coverage and the share outside the estimation
    domain on held-out data (``interval_coverage_val``, ``outside_domain_val``). Fields from the network that are
    missing or malformed are left out, never raised on; not escaped."""
    from streamid.model.uncertainty import DEFAULT_LEVEL

    model = up.model
    cal = model.metrics.get("calibration") if isinstance(model.metrics, dict) else None
    cal = cal if isinstance(cal, dict) else {}
    iv = getattr(model, "interval", None)
    if iv is None:
        reason = cal.get("reason")
        text = "no interval" + (f" ({reason if len(reason) <= 120 else reason[:117] + '...'})"
                                if isinstance(reason, str) and reason else "")
    else:  # a parsed model's interval is valid (Interval checks it); the default level, else the nearest one
        level, q = min(zip(iv.levels, iv.quantiles), key=lambda lq: abs(lq[0] - DEFAULT_LEVEL))
        text = f"interval {100 * level:g} % FR -+ {q:.3g} x ({iv.scale:.4g} + spread)"
        r2 = cal.get("r2_fr_held_out")
        if isinstance(r2, (int, float)) and not isinstance(r2, bool) and abs(r2) < 1e6:
            text += f", calibration held-out FR R2 {r2:.4f}"
    m = up.metrics if isinstance(up.metrics, dict) else {}
    cov, out = _share(m.get("interval_coverage_val")), _share(m.get("outside_domain_val"))
    held = []
    if cov is not None:
        held.append(f"covers {100 * cov:.1f} %")
    if out is not None:
        held.append(f"{100 * out:.1f} % outside the estimation domain")
    return text + (f"; on held-out data {', '.join(held)}" if held else "")


def format_update(up: Any, now_ns: int | None = None) -> str:
    """One line: stream, version, output and lags, validation R^2, age, and why it was accepted or rejected.

    Everything that came from the network is escaped (:func:`streamid.wire.names.printable`).
    """
    now_ns = time.time_ns() if now_ns is None else now_ns
    m = up.metrics
    age = max(0.0, (now_ns - up.published_unix_ns) / 1e9) if up.published_unix_ns else float("nan")
    output = getattr(up, "output", None) or up.model.output_name
    head = f"{up.stream} v{up.version}" if getattr(up, "accepted", True) else \
        f"{up.stream} challenger rejected (serving v{up.version})"
    why = decision_text(up)
    order = up.model.linear_order  # a dense linear ARX part (the online long linear part)
    ll = f" + linear ARX part of order {order}" if order else ""
    return printable(
        f"{head} {_how(up)} "
        f"{output}(t) = F[{up.model.lags_text()}]{ll} R2 val OSA {_r2(m.get('r2_osa_val'))} FR {_r2(m.get('r2_fr_val'))} "
        f"ident {up.identification_s:.2f}s age {age:.1f}s; {interval_part(up)}" + (f"; {why}" if why else ""),
        2000,
    )


def format_origin(up: Any, first: bool) -> str:
    """The line saying which daemon publishes a stream's models (``first``: else, a new daemon life began)."""
    o = up.origin
    try:
        began = datetime.datetime.fromtimestamp(o.epoch_ns / 1e9, tz=datetime.timezone.utc).isoformat(timespec="seconds")
    except (OverflowError, OSError, ValueError):
        began = f"{o.epoch_ns} ns"
    what = "models from daemon" if first else "a new daemon life: models from daemon"
    return printable(f"{up.stream}: {what} {o.daemon}, life began {began}" + ("" if first else
                     f" (versions count from v{up.version} again)"), 500)


def run(args: argparse.Namespace) -> int:
    from streamid.transport.client import STATUS_SKIPS, ModelSubscriber
    from streamid.wire.status_events import StatusEvent
    from streamid.commands.zenoh_flags import settings_from_args

    if args.count is not None and args.count < 1:
        raise ConfigError(f"--count must be an integer >= 1; got {args.count}")
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be a number of seconds > 0; got {args.duration}")
    if not args.every >= 0:
        raise ConfigError(f"--every must be a number of seconds >= 0; got {args.every}")
    stop = threading.Event()  # the watch ends (a signal, --duration, --count)
    halt = threading.Event()  # and ends now: a signal or --duration (no saving of what is still pending)
    end = None if args.duration is None else time.monotonic() + args.duration

    def halted() -> bool:
        if end is not None and time.monotonic() >= end:
            halt.set()
        return halt.is_set()

    saver = None
    if args.save_fmu:
        from streamid.export.saver import FmuSaver, SaveBounds

        saver = FmuSaver(args.save_fmu, SaveBounds(keep=args.keep, max_bytes=args.max_bytes,
                                                   max_pending=args.max_pending), halted=halted)
    seen = [0]
    origins: dict[str, Any] = {}
    out_lock = threading.Lock()
    count_lock = threading.Lock()

    def emit(text: str) -> None:
        with out_lock:
            print(text, flush=True)

    def on_update(up: Any) -> None:
        with count_lock:  # updates arrive on the transport's threads: --count N prints exactly N
            if args.count is not None and seen[0] >= args.count:
                return
            seen[0] += 1
            last = args.count is not None and seen[0] >= args.count
        prev = origins.get(up.stream)
        if not args.json and up.accepted and up.origin is not None and up.origin != prev and len(origins) < 10_000:
            origins[up.stream] = up.origin
            emit(format_origin(up, prev is None))
        emit(json.dumps(up.document) if args.json else format_update(up))  # json.dumps escapes non-ASCII
        if saver is not None and up.accepted:
            saver.offer(up)
        if last:
            stop.set()  # after its line is out

    def on_event(ev: StatusEvent) -> None:  # what the streams' status says has changed (ModelSubscriber's)
        emit(json.dumps(ev.to_dict()) if args.json else ev.text())

    settings = settings_from_args(args)
    where = ", ".join(settings.connect) or ", ".join(f"listening on {e}" for e in settings.listen) or "the --zenoh-config endpoints"
    timed_out = False
    skipped: dict[str, int] = {}

    def on_signal(*_: object) -> None:
        halt.set()
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        bus = _open_bus(settings, stop, where, args.duration)
        if bus is None:  # --duration (or a signal) ended the wait for the endpoint
            timed_out = not stop.is_set()
        else:
            with bus:
                wait = 5.0 if args.duration is None else min(5.0, args.duration)
                if not bus.wait_connected(wait):
                    print(f"streamid watch: nothing reachable at {where} yet (no daemon or router there); still trying",
                          file=sys.stderr, flush=True)
                with ModelSubscriber(bus, args.stream, on_update, include_rejected=args.rejected,
                                     on_event=on_event) as sub:
                    if not sub.latest:
                        print(f"streamid watch: waiting for models on {args.stream!r} ...", file=sys.stderr, flush=True)
                    next_age = time.monotonic() + args.every if args.every else None
                    while not stop.wait(0.1):
                        if saver is not None:
                            saver.save_pending()
                        now = time.monotonic()
                        if end is not None and now >= end:
                            timed_out = True
                            break
                        if next_age is not None and now >= next_age:
                            next_age = now + args.every
                            for name in sorted(sub.latest):
                                for up in sub.latest_per_output(name).values():
                                    emit(format_update(up))
                    skipped = {k: v for k, v in sub.skipped.items() if v}
                if saver is not None:
                    saver.save_pending()  # the updates of the last moments (--count) too, unless halted
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    for what, counts in (("model updates", {k: v for k, v in skipped.items() if k not in STATUS_SKIPS}),
                         ("status messages", {k: v for k, v in skipped.items() if k in STATUS_SKIPS})):
        if counts:
            print(f"streamid watch: skipped {sum(counts.values())} invalid {what} ("
                  + ", ".join(f"{k}: {v}" for k, v in counts.items()) + ")", file=sys.stderr, flush=True)
    if saver is not None and (saver.dropped or saver.failed or saver.pending):
        print(f"streamid watch: --save-fmu saved {saver.saved} FMU(s); {saver.dropped} pending model(s) dropped for "
              f"newer ones, {saver.failed} not saved, {saver.pending} still pending when stopped", file=sys.stderr,
              flush=True)
    if timed_out and seen[0] == 0:
        print(f"streamid watch: no model received from {where} in {args.duration:g} s", file=sys.stderr, flush=True)
        return 1
    return 0


def _open_bus(settings: Any, stop: threading.Event, where: str, duration_s: float | None) -> Any:
    """The session (a Bus); a client whose endpoint does not answer yet says so once and waits.

    It waits until stopped, ``--connect-wait`` or ``--duration``; None when that ended the wait.
    """
    from streamid.errors import TransportError
    from streamid.transport import Bus

    if settings.resolved_mode() != "client":
        return Bus(settings, stop=stop)
    try:
        return Bus(dataclasses.replace(settings, connect_wait_s=0.0))
    except TransportError as exc:
        if "cannot connect" not in str(exc):
            raise
    print(f"streamid watch: nothing reachable at {where} yet (no daemon or router there); still trying",
          file=sys.stderr, flush=True)
    wait_s = settings.connect_wait_s
    if duration_s is not None:
        wait_s = duration_s if wait_s is None else min(wait_s, duration_s)
    try:
        return Bus(dataclasses.replace(settings, connect_wait_s=wait_s), stop=stop)
    except TransportError as exc:
        if "cannot connect" in str(exc) and (stop.is_set() or wait_s is not None):
            return None
        raise
