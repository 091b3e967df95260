"""Record Zenoh traffic to an MCAP log.

The Zenoh subscriber callback only timestamps the payload and queues it; a
writer thread appends to the MCAP file, closing a chunk at least every
``chunk_interval_s`` so that a recorder killed with SIGKILL leaves every
complete chunk readable.  The queue is bounded: when the disk cannot keep up
the callback blocks, which back-pressures Zenoh (publishers use BLOCK
congestion control) instead of dropping samples.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from streamid.wire import codec
from streamid.errors import CodecError, ConfigError, LogError
from streamid.logs import LogWriter
from streamid.transport import Bus, ZenohSettings

__all__ = ["RecorderConfig", "RecordStats", "Recorder", "record"]

@dataclass(frozen=True)
class RecorderConfig:
    """What and how to record.

    Parameters
    ----------
    key_exprs : tuple of str
        Zenoh key expressions to record (default ``("streamid/**",)``).
    chunk_bytes : int
        Uncompressed size at which an MCAP chunk is closed.
    chunk_interval_s : float
        A chunk is closed at the latest this long after its first message.
    queue_messages : int
        Bound of the receive queue (back-pressure beyond it).
    metadata : tuple of (str, str)
        Extra metadata written in the log's ``streamid`` metadata record.
    """

    key_exprs: tuple[str, ...] = ("streamid/**",)
    chunk_bytes: int = 1 << 20
    chunk_interval_s: float = 1.0
    queue_messages: int = 10_000
    metadata: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.key_exprs, str) or not self.key_exprs:
            raise ConfigError(
                f"key_exprs must be a non-empty tuple of Zenoh key expressions; got {self.key_exprs!r}"
            )
        object.__setattr__(self, "key_exprs", tuple(self.key_exprs))
        if self.queue_messages < 1:
            raise ConfigError(f"queue_messages must be >= 1; got {self.queue_messages!r}")
        if not self.chunk_interval_s > 0:
            raise ConfigError(f"chunk_interval_s must be > 0 s; got {self.chunk_interval_s!r}")


@dataclass
class RecordStats:
    """What a recorder wrote: counts per key, sequence gaps, timing."""

    path: Path
    messages: int = 0
    bytes: int = 0
    samples: int = 0
    per_key: dict[str, int] = field(default_factory=dict)
    seq_gaps: int = 0
    seq_out_of_order: int = 0
    max_queue: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def duration_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9

    def summary(self) -> str:
        keys = ", ".join(f"{k}: {n}" for k, n in sorted(self.per_key.items())) or "none"
        return (
            f"recorded {self.messages} messages ({self.samples} samples, {self.bytes} bytes) over "
            f"{self.duration_s:.3f} s to {self.path}; per key: {keys}; sequence gaps: "
            f"{self.seq_gaps}, out of order: {self.seq_out_of_order}; max queue: {self.max_queue}"
        )


class Recorder:
    """Subscribe to key expressions and write every sample to an MCAP log.

    Use as a context manager, or call :meth:`start` and :meth:`stop`.

    Parameters
    ----------
    path : str or Path
        The MCAP file to write.
    settings : ZenohSettings, optional
        How to open the Zenoh session (ignored when ``bus`` is given).
    config : RecorderConfig, optional
    bus : Bus, optional
        An open session to use instead of opening one (not closed by the recorder).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        settings: ZenohSettings | None = None,
        config: RecorderConfig | None = None,
        *,
        bus: Bus | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        self.path = Path(path)
        self._stop_waiting = stop  # ends a client's wait for its router at start
        self.settings = settings if settings is not None else ZenohSettings()
        self.config = config if config is not None else RecorderConfig()
        self.stats = RecordStats(self.path)
        self._bus = bus
        self._own_bus = bus is None
        # (key, receive time ns, payload); None asks the writer thread to stop
        self._q: queue.Queue[tuple[str, int, bytes] | None] = queue.Queue(self.config.queue_messages)
        self._writer: LogWriter | None = None
        self._thread: threading.Thread | None = None
        self._handles: list[object] = []
        self._error: BaseException | None = None
        self._last_seq: dict[str, int] = {}
        self._count_lock = threading.Condition()
        self._received = 0
        self._stopping = False

    # -- lifecycle -------------------------------------------------------
    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def start(self) -> Recorder:
        """Create the log, start the writer thread and subscribe."""
        if self._writer is not None:
            raise LogError(f"recorder for {str(self.path)!r} already started")
        meta = {"recorder": "streamid record", "key_exprs": " ".join(self.config.key_exprs)}
        meta.update(dict(self.config.metadata))
        self._writer = LogWriter(
            self.path, chunk_bytes=self.config.chunk_bytes,
            chunk_interval_s=self.config.chunk_interval_s, metadata=meta,
        )
        self._thread = threading.Thread(target=self._run, name="streamid-recorder", daemon=True)
        self._thread.start()
        try:
            if self._bus is None:
                self._bus = Bus(self.settings, stop=self._stop_waiting)
            for expr in self.config.key_exprs:
                self._handles.append(self._bus.subscribe(expr, self._on_sample))
        except BaseException:
            self.stop()
            raise
        return self

    def _on_sample(self, key: str, payload: bytes) -> None:
        item = (key, time.time_ns(), payload)
        while True:
            if self._error is not None or self._stopping and self._thread is None:
                return
            try:
                self._q.put(item, timeout=0.5)
                break
            except queue.Full:
                continue
        with self._count_lock:
            self._received += 1
            self._count_lock.notify_all()

    def _run(self) -> None:
        writer = self._writer
        assert writer is not None
        st = self.stats
        try:
            while True:
                try:
                    item = self._q.get(timeout=0.1)
                except queue.Empty:
                    writer.maybe_flush()
                    continue
                if item is None:
                    return
                st.max_queue = max(st.max_queue, self._q.qsize() + 1)
                key, t_ns, data = item
                head = codec.peek_header(data)
                if head is not None:
                    seq, t0 = head
                    last = self._last_seq.get(key)
                    if last is not None:
                        if seq > last + 1:
                            st.seq_gaps += 1
                        elif seq <= last:
                            st.seq_out_of_order += 1
                    self._last_seq[key] = seq if last is None else max(seq, last)
                    writer.write(key, data, t_ns, t0, seq)
                    st.samples += _sample_count(data)
                else:
                    writer.write(key, data, t_ns, t_ns, 0)
                st.messages += 1
                st.bytes += len(data)
                st.per_key[key] = st.per_key.get(key, 0) + 1
                if st.first_ns is None:
                    st.first_ns = t_ns
                st.last_ns = t_ns
        except BaseException as exc:  # noqa: BLE001 - reported by stop()
            self._error = exc

    # -- waiting ---------------------------------------------------------
    @property
    def received(self) -> int:
        """Messages received so far (queued or written)."""
        return self._received

    def wait_for(self, n_messages: int, timeout_s: float) -> bool:
        """Block until ``n_messages`` were received or ``timeout_s`` passed."""
        deadline = time.monotonic() + timeout_s
        with self._count_lock:
            while self._received < n_messages:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._count_lock.wait(min(left, 0.1))
        return True

    def wait_idle(self, idle_s: float, timeout_s: float) -> int:
        """Block until nothing arrived for ``idle_s`` (or ``timeout_s``); return the count."""
        deadline = time.monotonic() + timeout_s
        last = -1
        quiet_since = time.monotonic()
        while time.monotonic() < deadline:
            now = self._received
            if now != last:
                last, quiet_since = now, time.monotonic()
            elif time.monotonic() - quiet_since >= idle_s:
                break
            time.sleep(min(0.02, idle_s))
        return self._received

    def stop(self) -> RecordStats:
        """Unsubscribe, write everything queued, finish the file; return the stats."""
        self._stopping = True
        for h in self._handles:
            h.close()  # type: ignore[attr-defined]
        self._handles.clear()
        if self._own_bus and self._bus is not None:
            self._bus.close()
        if self._thread is not None:
            self._q.put(None)
            self._thread.join()
            self._thread = None
        if self._writer is not None:
            self._writer.close()
        if self._error is not None:
            raise LogError(f"recorder writing {str(self.path)!r} failed: {self._error!r}") from self._error
        return self.stats


def _sample_count(data: bytes) -> int:
    try:
        return len(codec.decode(data))
    except CodecError:
        return 0


def record(
    path: str | os.PathLike[str],
    settings: ZenohSettings | None = None,
    config: RecorderConfig | None = None,
    *,
    duration_s: float | None = None,
    max_messages: int | None = None,
    stop_event: threading.Event | None = None,
    ready: threading.Event | None = None,
) -> RecordStats:
    """Record until ``duration_s`` elapsed, ``max_messages`` arrived or ``stop_event`` is set.

    At least one bound must be given (an unbounded recording needs a
    ``stop_event``, e.g. set by a signal handler).  ``ready`` is set once the
    subscriptions are declared.
    """
    if duration_s is None and max_messages is None and stop_event is None:
        raise ConfigError("record needs a bound: duration_s, max_messages or stop_event")
    if duration_s is not None and not duration_s > 0:
        raise ConfigError(f"duration_s must be > 0 seconds; got {duration_s!r}")
    stop = stop_event if stop_event is not None else threading.Event()
    rec = Recorder(path, settings, config, stop=stop)
    rec.start()
    try:
        if ready is not None:
            ready.set()
        deadline = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            if max_messages is not None and rec.received >= max_messages:
                break
            stop.wait(0.05)
    finally:
        stats = rec.stop()
    return stats
