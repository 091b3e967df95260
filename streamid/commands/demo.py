"""``streamid demo``: the main job in one command, on loopback, in about a minute.

Starts the identification daemon on a free loopback port, replays two bundled
logs onto Zenoh as if a dSPACE board and a sensor were live -- the real MR damper
(velocity -> force, 200 Hz) and the simulated piezo micromanipulator (voltage ->
deflection, 20 kHz), both in real time and looped over the same 60 s -- and
prints every model the daemon publishes as it arrives.  Ends with a summary
table and the ``.rrd`` file of the diagnostics with the command that opens it
in the Rerun viewer.  No router, viewer or configuration needed.

Exit code 0 only if models were published for both streams.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from streamid.errors import ConfigError

__all__ = ["DemoStream", "DEMO_STREAMS", "register", "run"]


@dataclass(frozen=True)
class DemoStream:
    """One replayed log and how the daemon windows it."""

    stream: str
    log: str  # bundled log name
    rate: float  # replay speed (1.0 = real time)
    loops: int  # times the log is played
    end_s: float  # play the first end_s seconds of the log on each pass
    window_s: float  # stream time
    update_every_s: float  # stream time
    neurons: int
    max_lag: int
    description: str

    @property
    def wall_s(self) -> float:
        return self.end_s * self.loops / self.rate


#: Both streams cover the same 60 s of stream time, so that the end of the recording
#: (where the Rerun viewer's cursor follows) holds the newest update of each.
DEMO_STREAMS: tuple[DemoStream, ...] = (
    DemoStream("mr_damper", "mr_damper", rate=1.0, loops=4, end_s=15.0, window_s=4.0, update_every_s=1.0,
               neurons=10, max_lag=10, description="real MR damper, 200 Hz, first 15 s looped"),
    DemoStream("piezo", "piezo_sim_20khz", rate=1.0, loops=3, end_s=20.0, window_s=0.5, update_every_s=1.0,
               neurons=10, max_lag=10, description="simulated piezo, 20 kHz"),
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "demo",
        help="replay the bundled MR damper and piezo logs through the daemon and show the models (about 1 min)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", default="streamid-demo", metavar="DIR",
                   help="where the .rrd, the daemon's config and its log go (default ./streamid-demo)")
    p.add_argument("--loops", type=int, default=None, metavar="N",
                   help="play each log N times (default: 4 x 15 s of the MR damper, 3 x 20 s of the piezo: a minute)")
    p.add_argument("--port", type=int, default=0, help="loopback TCP port of the daemon (default: a free one)")
    p.add_argument("--screenshot", metavar="PNG", default=None,
                   help="afterwards, render the .rrd with the real Rerun viewer (headless) into PNG "
                        "(needs a GPU or `apt-get install mesa-vulkan-drivers`)")
    p.set_defaults(func=run)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_listening(port: int, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ConfigError(f"the daemon exited at start with code {proc.returncode}; see its log")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise ConfigError(f"the daemon did not listen on 127.0.0.1:{port} within {timeout_s:.0f} s")


def _config_toml(streams: Sequence[DemoStream]) -> str:
    lines = [
        "# written by `streamid demo`",
        "[daemon]",
        f"streams = [{', '.join(repr(s.stream).replace(chr(39), chr(34)) for s in streams)}]",
        f"workers = {min(2, os.cpu_count() or 1)}",
        "",
    ]
    for s in streams:
        lines += [
            f"[streams.{s.stream}]",
            f"window_s = {s.window_s}",
            f"update_every_s = {s.update_every_s}",
            f"neurons = {s.neurons}",
            f"max_lag_y = {s.max_lag}",
            f"max_lag_u = {s.max_lag}",
            "",
        ]
    return "\n".join(lines)


@dataclass
class _Tally:
    versions: list[int] = field(default_factory=list)
    last: Any = None
    ident_s: list[float] = field(default_factory=list)
    latency_s: list[float] = field(default_factory=list)
    decision_s: list[float] = field(default_factory=list)  # window closed -> decided, accepted or rejected
    fr_val: list[float] = field(default_factory=list)  # free-run R2 of each published model on its held-out data
    rejected: int = 0


def _replayed_samples(replay: subprocess.Popen[bytes]) -> int | None:
    """The samples a finished ``streamid replay --json`` put (None if it printed no report)."""
    import json

    if replay.poll() is None or replay.stdout is None:
        return None
    lines = replay.stdout.read().decode("utf-8", "replace").strip().splitlines()
    try:
        return int(json.loads(lines[-1])["samples"])
    except (IndexError, ValueError, KeyError, TypeError):
        return None


def _settled(status: dict[str, Any] | None, sent: int | None, tally: _Tally) -> bool:
    """Whether a stream's daemon status shows every replayed sample in, nothing left to identify, and the
    newest model it published already received by us."""
    if status is None or sent is None or status.get("samples_in", 0) < sent:
        return False
    if status.get("busy") or status.get("windows", {}).get("pending"):
        return False
    version = int(status.get("version") or 0)
    return version == 0 or (bool(tally.versions) and max(tally.versions) >= version)


def _line(t0: float, up: Any) -> str:
    from streamid.commands.watch import format_update

    return f"[{time.monotonic() - t0:5.1f} s] {format_update(up)}"


def run(args: argparse.Namespace) -> int:
    from streamid.transport.client import ModelSubscriber, latest_status
    from streamid.transport import Bus, ZenohSettings

    if args.loops is not None and args.loops < 1:
        raise ConfigError(f"--loops must be a whole number >= 1, got {args.loops}")
    streams = tuple(
        s if args.loops is None else DemoStream(**{**s.__dict__, "loops": args.loops}) for s in DEMO_STREAMS
    )
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    rrd = out / "demo.rrd"
    for old in out.glob("demo*.rrd"):
        old.unlink()
    cfg = out / "daemon.toml"
    cfg.write_text(_config_toml(streams), encoding="utf-8")
    port = args.port or _free_port()
    ep = f"tcp/127.0.0.1:{port}"
    py = [sys.executable, "-m", "streamid"]

    durations = {s.stream: s.wall_s for s in streams}
    expected_s = max(durations.values())
    print(f"streamid demo: daemon on {ep}, diagnostics -> {rrd}")
    for s in streams:
        print(f"  {s.stream:<9} {s.description}: log '{s.log}' x{s.loops}, window {s.window_s} s, "
              f"update every {s.update_every_s} s  (~{durations[s.stream]:.0f} s)")
    print(f"  expected run time ~{expected_s:.0f} s plus the first (cold) identifications\n", flush=True)

    daemon_log = open(out / "daemon.log", "wb")
    daemon = subprocess.Popen(
        [*py, "daemon", "--config", str(cfg), "--listen", ep, "--rrd", str(rrd), "--rrd-rotate-mb", "0"],
        stdout=daemon_log, stderr=subprocess.STDOUT,
    )
    replays: list[subprocess.Popen[bytes]] = []
    tallies = {s.stream: _Tally() for s in streams}
    lock = threading.Lock()
    t0 = time.monotonic()

    def on_update(up: Any) -> None:
        with lock:
            t = tallies.get(up.stream)
            if t is None:
                return
            if up.window_closed_unix_ns and up.published_unix_ns:
                t.decision_s.append((up.published_unix_ns - up.window_closed_unix_ns) / 1e9)
            if not up.accepted:  # a challenger that did not beat the champion: counted, not printed
                t.rejected += 1
                return
            t.fr_val.append(float(up.metrics.get("r2_fr_val", float("nan"))))
            t.versions.append(up.version)
            t.last = up
            t.ident_s.append(up.identification_s)
            if up.window_closed_unix_ns and up.published_unix_ns:
                t.latency_s.append((up.published_unix_ns - up.window_closed_unix_ns) / 1e9)
            print(_line(t0, up), flush=True)

    client = ZenohSettings(connect=(ep,))
    statuses: dict[str, Any] = {}
    try:
        _wait_listening(port, daemon, 30.0)
        with Bus(client) as bus, ModelSubscriber(bus, "*", on_update, fetch_latest=False,
                                                      include_rejected=True):
            bus.wait_connected(10.0)  # so that no early model is published before we listen
            for s in streams:
                replays.append(subprocess.Popen(
                    [*py, "replay", s.log, "--connect", ep, "--rate", str(s.rate), "--loop", str(s.loops),
                     "--end", str(s.end_s), "--stream", s.stream, "--json"],
                    stdout=subprocess.PIPE, stderr=open(out / f"replay-{s.stream}.log", "wb"),
                ))
            deadline = time.monotonic() + 3 * expected_s + 60
            for r in replays:
                r.wait(timeout=max(1.0, deadline - time.monotonic()))
            sent = {s.stream: _replayed_samples(r) for s, r in zip(streams, replays)}
            # let the last windows be identified and published: until the daemon says (asked now, not its last
            # periodic status) that every sample replayed is in and no window waits or is being identified, and
            # its newest model has reached us; at most 8 s (the fixed wait this replaces)
            settle = time.monotonic() + 8.0
            while True:
                for s in streams:
                    statuses[s.stream] = latest_status(bus, s.stream, timeout_s=2.0)
                with lock:
                    done = all(_settled(statuses[s.stream], sent[s.stream], tallies[s.stream]) for s in streams)
                if done or time.monotonic() >= settle:
                    break
                time.sleep(0.25)
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
    finally:
        for r in replays:
            if r.poll() is None:
                r.terminate()
                r.wait(timeout=5)
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGINT)
            try:
                daemon.wait(timeout=15)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.wait()
        daemon_log.close()

    print()
    print(_summary(streams, tallies, statuses))
    print(f"\ndiagnostics: {rrd}\nopen them:   rerun {rrd}")
    print(f"daemon log:  {out / 'daemon.log'}")
    if args.screenshot:
        from streamid.viz.rerun_view import screenshot

        try:
            print(f"screenshot:  {screenshot(rrd, args.screenshot)}")
        except (OSError, RuntimeError) as exc:
            print(f"screenshot failed: {exc}", file=sys.stderr)
            return 1
    missing = [s.stream for s in streams if not tallies[s.stream].versions]
    if missing:
        print(f"no model was published for: {', '.join(missing)} (see {out / 'daemon.log'})", file=sys.stderr)
        return 1
    return 0


def _summary(streams: Sequence[DemoStream], tallies: dict[str, _Tally], statuses: dict[str, Any]) -> str:
    head = ("stream", "models", "rejected", "last v", "lags (last)", "R2 OSA val", "R2 FR val",
            "min FR val after 1st", "ident median s", "decided median/max s", "samples in", "bad msgs")
    rows = [head]
    for s in streams:
        t = tallies[s.stream]
        st = statuses.get(s.stream) or {}
        samples_in = st.get("samples_in", "n/a")
        bad = st.get("bad_total", "n/a")
        if t.last is None:
            rows.append((s.stream, "0", str(t.rejected), "-", "-", "-", "-", "-", "-", "-", str(samples_in), str(bad)))
            continue
        m = t.last.metrics
        rows.append((
            s.stream, str(len(t.versions)), str(t.rejected), str(t.last.version),
            t.last.model.lags_text(),
            f"{m.get('r2_osa_val', float('nan')):.4f}", f"{m.get('r2_fr_val', float('nan')):.4f}",
            f"{min(t.fr_val[1:]):.4f}" if len(t.fr_val) > 1 else "-",
            f"{statistics.median(t.ident_s):.3f}",
            f"{statistics.median(t.decision_s):.3f}/{max(t.decision_s):.3f}" if t.decision_s else "n/a",
            str(samples_in), str(bad),
        ))
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
