"""Play a streamid MCAP log onto Zenoh.

Timing: message ``i`` is put at ``start + (log_time_i - log_time_0) / rate``
(``rate`` 1.0 = real time); ``max_speed`` puts as fast as Zenoh accepts (BLOCK
congestion control: nothing is dropped).  The payload put on Zenoh is the
MCAP message's bytes, unchanged, so recording a replay gives back the same
messages -- except when ``stream`` remapping is asked for (the stream name
inside each batch is rewritten to match the new key) and on the second and
later passes of a loop (sequence numbers and sample times are shifted so that
the stream continues forward in time instead of jumping back).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from streamid.wire import codec
from streamid.errors import CodecError, ConfigError
from streamid.wire.keys import SAMPLE_KINDS, check_stream_name, parse_key
from streamid.logs import LogMessage, LogReader
from streamid.transport import Bus, BusPublisher, ZenohSettings

__all__ = ["ReplayConfig", "ReplayReport", "replay_log", "parse_stream_map"]

_log = logging.getLogger(__name__)
_SPIN_NS = 300_000  # busy-wait the last 0.3 ms before a put for precise timing
_READ_SLACK_NS = 5_000_000  # read ahead only with more than 5 ms to spare


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay a log.

    Parameters
    ----------
    rate : float
        Time scale: 1.0 real time, 2.0 twice as fast (ignored with ``max_speed``).
    max_speed : bool
        Put messages back to back, as fast as possible.
    loops : int
        Passes over the log; 0 = until stopped.
    start_s, end_s : float
        Replay only messages logged in ``[start_s, end_s)`` seconds after the
        log's first message (``end_s=None``: to the end).
    stream_map : tuple of (str, str)
        Stream remapping ``(old, new)``; ``old == "*"`` maps every stream.
    keys : tuple of str, optional
        Replay only these keys (topics), before remapping.
    wait_subscribers_s : float
        Before the first put, wait up to this long for a subscriber to match.
    partial : bool
        Replay every complete chunk of a truncated or corrupt log.
    """

    rate: float = 1.0
    max_speed: bool = False
    loops: int = 1
    start_s: float = 0.0
    end_s: float | None = None
    stream_map: tuple[tuple[str, str], ...] = ()
    keys: tuple[str, ...] | None = None
    wait_subscribers_s: float = 5.0
    partial: bool = False

    def __post_init__(self) -> None:
        if not (self.rate > 0 and np.isfinite(self.rate)):
            raise ConfigError(f"rate must be a finite number > 0 (1.0 = real time); got {self.rate!r}")
        if not isinstance(self.loops, int) or self.loops < 0:
            raise ConfigError(f"loops must be an integer >= 0 (0 = until stopped); got {self.loops!r}")
        if not self.start_s >= 0:
            raise ConfigError(f"start_s must be >= 0 seconds; got {self.start_s!r}")
        if self.end_s is not None and not self.end_s > self.start_s:
            raise ConfigError(f"end_s must be > start_s = {self.start_s} s; got {self.end_s!r}")
        if not self.wait_subscribers_s >= 0:
            raise ConfigError(f"wait_subscribers_s must be >= 0 s; got {self.wait_subscribers_s!r}")
        for old, new in self.stream_map:
            if old != "*":
                check_stream_name(old)
            check_stream_name(new)


def parse_stream_map(specs: list[str] | tuple[str, ...] | None) -> tuple[tuple[str, str], ...]:
    """``["NEW"]`` -> every stream to NEW; ``["OLD=NEW", ...]`` -> each OLD to its NEW."""
    out: list[tuple[str, str]] = []
    for spec in specs or ():
        old, sep, new = spec.partition("=")
        pair = (old, new) if sep else ("*", old)
        if not pair[0] or not pair[1]:
            raise ConfigError(f"--stream takes NEW or OLD=NEW; got {spec!r}")
        out.append(pair)
    if any(o == "*" for o, _ in out) and len(out) > 1:
        raise ConfigError(f"--stream NEW (map every stream) cannot be combined with others; got {specs}")
    return tuple(out)


@dataclass
class ReplayReport:
    """What a replay did and how precisely it kept time."""

    path: Path
    messages: int = 0
    samples: int = 0
    bytes: int = 0
    passes: int = 0
    wall_s: float = 0.0
    log_span_s: float = 0.0
    per_key: dict[str, int] = field(default_factory=dict)
    #: time at which the put started minus its scheduled time, ns (timed replays only)
    lateness_ns: list[int] = field(default_factory=list)
    problem: str | None = None
    #: wall-clock time (``time.time_ns()``) of the first put
    started_ns: int | None = None
    #: keys published on which no subscriber was ever seen (nothing received them)
    unheard_keys: list[str] = field(default_factory=list)
    #: the endpoints the session connected to (for the message when nobody listened)
    endpoints: tuple[str, ...] = ()

    @property
    def samples_per_s(self) -> float:
        return self.samples / self.wall_s if self.wall_s > 0 else 0.0

    def timing_error_us(self) -> dict[str, float]:
        """Distribution of |put time - scheduled time| in µs: p50, p90, p99, max, mean."""
        if not self.lateness_ns:
            return {}
        a = np.abs(np.asarray(self.lateness_ns, dtype=np.float64)) / 1e3
        return {
            "p50": float(np.percentile(a, 50)), "p90": float(np.percentile(a, 90)),
            "p99": float(np.percentile(a, 99)), "max": float(a.max()), "mean": float(a.mean()),
            "n": float(a.size),
        }

    def summary(self) -> str:
        text = (
            f"replayed {self.messages} messages ({self.samples} samples, {self.bytes} bytes) in "
            f"{self.wall_s:.3f} s ({self.samples_per_s:,.0f} samples/s) from {self.path}, "
            f"{self.passes} pass(es)"
        )
        err = self.timing_error_us()
        if err:
            text += (
                f"; timing error (put start - schedule) µs: p50 {err['p50']:.1f}, p90 {err['p90']:.1f}, "
                f"p99 {err['p99']:.1f}, max {err['max']:.1f}"
            )
        if self.problem:
            text += f"; log problem: {self.problem}"
        if self.unheard_keys:
            where = f" via {', '.join(self.endpoints)}" if self.endpoints else ""
            text += (
                f"\nno subscriber{where} on {', '.join(self.unheard_keys)}: nothing received these messages "
                "(is `streamid daemon` running and reachable there?)"
            )
        return text


class _Remapper:
    """Key and payload rewriting for one pass (stream remap + loop shift)."""

    def __init__(self, stream_map: Mapping[str, str]) -> None:
        self.map = dict(stream_map)
        self.seq_shift = 0
        self.time_shift_ns = 0

    def key(self, key: str) -> tuple[str, str | None, str | None]:
        try:
            stream, kind = parse_key(key)
        except ConfigError:
            return key, None, None
        new = self.map.get(stream, self.map.get("*", stream))
        return f"streamid/{new}/{kind}", new, kind

    def payload(self, data: bytes, new_stream: str | None, kind: str | None,
                changed: bool) -> bytes:
        if kind not in SAMPLE_KINDS or (not changed and not self.seq_shift and not self.time_shift_ns):
            return data
        try:
            b = codec.decode(data)
        except CodecError:
            return data  # not a batch: forwarded as is
        t_ns = None if b.t_ns is None else b.t_ns + self.time_shift_ns
        return codec.encode(codec.SampleBatch(
            new_stream or b.stream, b.seq + self.seq_shift, b.t0_ns + self.time_shift_ns,
            b.period_ns, t_ns, b.inputs, b.outputs,
        ))


class _ReadAhead:
    """Iterator over log messages that reads ahead when the caller has time to spare.

    Reading the next message may decompress a whole chunk (milliseconds); doing
    it while waiting for a message's scheduled time keeps that cost out of the
    timing.
    """

    def __init__(self, it: Iterator[LogMessage], limit: int = 4096) -> None:
        self._it = it
        self._buf: deque[LogMessage] = deque()
        self._limit = limit
        self._done = False

    def __iter__(self) -> _ReadAhead:
        return self

    def __next__(self) -> LogMessage:
        if self._buf:
            return self._buf.popleft()
        return next(self._it)

    def fill_until(self, deadline_ns: int) -> None:
        while (not self._done and len(self._buf) < self._limit
               and deadline_ns - time.perf_counter_ns() > _READ_SLACK_NS):
            try:
                self._buf.append(next(self._it))
            except StopIteration:
                self._done = True


def _sleep_until(target_ns: int, stop: threading.Event) -> None:
    while True:
        left = target_ns - time.perf_counter_ns()
        if left <= 0:
            return
        if left > _SPIN_NS:
            if stop.wait((left - _SPIN_NS) / 1e9):
                return
        # spin the last fraction of a millisecond


def _count_samples(data: bytes) -> int:
    try:
        return len(codec.decode(data))
    except CodecError:
        return 0


@dataclass(frozen=True)
class _Geometry:
    """What looping needs to know about the replayed range of a log."""

    msg_period_ns: int  # pass p starts p * msg_period_ns after pass 0
    data_period_ns: int  # sample times of pass p are shifted by p * data_period_ns
    seq_period: int  # sequence numbers of pass p are shifted by p * seq_period


def _in_range(rel_ns: int, cfg: ReplayConfig) -> int:
    """-1 before the range, 0 inside, 1 after."""
    if rel_ns < cfg.start_s * 1e9:
        return -1
    if cfg.end_s is not None and rel_ns >= cfg.end_s * 1e9:
        return 1
    return 0


def _geometry(path: Path, keys: frozenset[str] | None, cfg: ReplayConfig) -> _Geometry:
    first = None
    times: list[int] = []
    lo = hi = None
    period = 0
    max_seq = -1
    for key, log_ns, data in LogReader(path, keys=keys, partial=cfg.partial):
        first = log_ns if first is None else first
        where = _in_range(log_ns - first, cfg)
        if where < 0:
            continue
        if where > 0:
            break
        times.append(log_ns)
        try:
            b = codec.decode(data)
        except CodecError:
            continue
        t = b.times_ns()
        lo = int(t[0]) if lo is None else min(lo, int(t[0]))
        hi = int(t[-1]) if hi is None else max(hi, int(t[-1]))
        period = b.period_ns or period
        max_seq = max(max_seq, b.seq)
    if len(times) > 1:
        step = int(np.median(np.diff(np.asarray(times, dtype=np.int64))))
        msg_period = times[-1] - times[0] + max(step, 1)
    else:
        msg_period = 1_000_000
    if lo is None or hi is None:
        data_period = 0
    else:
        data_period = hi - lo + (period if period > 0 else max((hi - lo) // 1000, 1))
    return _Geometry(msg_period, data_period, max_seq + 1)


def replay_log(
    path: str | os.PathLike[str],
    settings: ZenohSettings | None = None,
    config: ReplayConfig | None = None,
    *,
    bus: Bus | None = None,
    stop_event: threading.Event | None = None,
    on_message: Callable[[str, bytes], None] | None = None,
) -> ReplayReport:
    """Replay the log at ``path`` onto Zenoh; return a :class:`ReplayReport`.

    Parameters
    ----------
    path : str or Path
        An MCAP log.
    settings : ZenohSettings, optional
        Session to open (ignored when ``bus`` is given).
    config : ReplayConfig, optional
    bus : Bus, optional
        An open session to publish on (left open).
    stop_event : threading.Event, optional
        Set it to stop early (e.g. from a signal handler).
    on_message : callable, optional
        Called with ``(key, payload)`` after each put.

    Raises
    ------
    LogError
        The log cannot be read (truncated/corrupt without ``partial``).
    ConfigError
        ``--stream NEW`` on a log holding several streams.
    """
    cfg = config if config is not None else ReplayConfig()
    path = Path(path)
    stop = stop_event if stop_event is not None else threading.Event()
    keys = frozenset(cfg.keys) if cfg.keys is not None else None
    LogReader(path)  # existence check before opening a session
    geo = _geometry(path, keys, cfg) if cfg.loops != 1 else _Geometry(0, 0, 0)
    report = ReplayReport(path)
    own_bus = bus is None
    if bus is None:
        bus = Bus(settings if settings is not None else ZenohSettings(), stop=stop)
    publishers: dict[str, BusPublisher] = {}
    heard: set[str] = set()
    report.endpoints = tuple(bus.settings.connect) or tuple(bus.settings.listen)
    remap = _Remapper(dict(cfg.stream_map))
    streams_seen: set[str] = set()
    start_ns = int(cfg.start_s * 1e9)
    wall0: int | None = None
    last_rel = 0
    try:
        n_pass = 0
        while (cfg.loops == 0 or n_pass < cfg.loops) and not stop.is_set():
            remap.seq_shift = n_pass * geo.seq_period
            remap.time_shift_ns = n_pass * geo.data_period_ns
            reader = LogReader(path, keys=keys, partial=cfg.partial)
            source = _ReadAhead(iter(reader))
            first: int | None = None
            sent = 0
            for key, log_ns, data in source:
                if stop.is_set():
                    break
                first = log_ns if first is None else first
                where = _in_range(log_ns - first, cfg)
                if where < 0:
                    continue
                if where > 0:
                    break
                new_key, new_stream, kind = remap.key(key)
                if kind is not None and "*" in remap.map:
                    streams_seen.add(key.split("/")[1])
                    if len(streams_seen) > 1:
                        raise ConfigError(
                            f"--stream NEW maps every stream to one name, but the log holds "
                            f"several streams {sorted(streams_seen)}; use OLD=NEW"
                        )
                payload = remap.payload(data, new_stream, kind, new_key != key)
                pub = publishers.get(new_key)
                if pub is None:
                    pub = bus.publisher(new_key, block=True)
                    publishers[new_key] = pub
                    if wall0 is None and cfg.wait_subscribers_s > 0:
                        if not pub.wait_for_subscribers(cfg.wait_subscribers_s):
                            _log.warning("no subscriber on %s after %.1f s; replaying anyway",
                                         new_key, cfg.wait_subscribers_s)
                    if pub.has_subscribers():
                        heard.add(new_key)
                rel = log_ns - first - start_ns + n_pass * geo.msg_period_ns
                last_rel = rel
                if wall0 is None:
                    report.started_ns = time.time_ns()
                    wall0 = time.perf_counter_ns()
                if cfg.max_speed:
                    pub.put(payload)
                else:
                    target = wall0 + int(rel / cfg.rate)
                    source.fill_until(target)  # read (and decompress) ahead in the slack
                    _sleep_until(target, stop)
                    if stop.is_set():
                        break
                    report.lateness_ns.append(time.perf_counter_ns() - target)
                    pub.put(payload)
                if on_message is not None:
                    on_message(new_key, payload)
                report.messages += 1
                report.bytes += len(payload)
                if kind in SAMPLE_KINDS:
                    report.samples += _count_samples(payload)
                report.per_key[new_key] = report.per_key.get(new_key, 0) + 1
                sent += 1
            if reader.problem:
                report.problem = reader.problem
            n_pass += 1
            report.passes = n_pass
            if sent == 0:
                break  # nothing in range: looping would spin
        if wall0 is not None:
            report.wall_s = (time.perf_counter_ns() - wall0) / 1e9
        report.log_span_s = last_rel / 1e9
    finally:
        for key, pub in publishers.items():
            if key not in heard and pub.has_subscribers():
                heard.add(key)
            pub.close()
        report.unheard_keys = sorted(set(publishers) - heard)
        if own_bus:
            bus.close()
    return report
