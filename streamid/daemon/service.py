"""The identification daemon: Zenoh in, windows, warm-started CoEA, models out.

Threads (no forked processes: Zenoh is not fork-safe, and nothing is pickled):

* **Zenoh's callback threads** run the receiving path only: split the key,
  :func:`streamid.wire.codec.decode`, :meth:`WindowBuffer.append`.  A closed window
  joins the stream's bounded queue of pending windows and wakes a worker.
* **Worker threads** (``daemon.workers``, default 1) take pending windows,
  oldest first, one stream at a time each (round robin between streams), run
  :func:`~streamid.online.update.identify_window`, save the state, publish the
  model and only then draw it in Rerun.  Each worker owns an
  :class:`~streamid.engine.parallel.EvalHelper` (``daemon.helper``): a fresh
  ``python -m`` process, started before the Zenoh session, sharing memory with
  the worker, that evaluates half of every population batch on otherwise idle
  CPU (SCHED_IDLE: it never takes a core from ingestion).  A helper that fails
  to start is reported once and the worker goes on alone.  A stream whose identification is still
  running keeps at most ``max_pending_windows`` (default 1) newer windows; a
  window closing beyond that drops the oldest (coalesced), so the backlog is
  bounded by construction (:mod:`streamid.online.pending`).
* **One housekeeping thread** declares the per-stream publishers and
  queryables, publishes status every ``status_every_s`` and forwards the
  buffers' events (gaps, resets, bad input) to the Rerun event log.

:meth:`Daemon.stop` sets a stop flag seen between two generations, undeclares
the subscriptions, joins the threads, saves the state and closes the Rerun
sinks (the ``.rrd`` footer is written) within the given deadline.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from streamid.wire.codec import decode
from streamid.daemon.config import DaemonConfig
from streamid.wire.documents import encode_json
from streamid.daemon.memory import retain_freed_memory
from streamid.daemon.runtime import StreamRuntime
from streamid.daemon.state_store import StateStore
from streamid.online.update import Outcome, Stopped, identify_window
from streamid.engine.parallel import EvalHelper
from streamid.errors import CodecError, ModelFormatError, StreamidError
from streamid.wire.keys import PREFIX, SAMPLE_KINDS, is_valid_stream_name, model_key, status_key
from streamid.transport import Bus, ZenohSettings

__all__ = ["Daemon"]

_log = logging.getLogger(__name__)
_OWN_KINDS = ("model", "status")


class Daemon:
    """The streaming identification service.

    Parameters
    ----------
    config
        Daemon and per-stream settings.
    zenoh
        How to open the Zenoh session.
    viz
        A :class:`streamid.viz.rerun_view.Viz` (or None: no diagnostics).
    state_dir
        Where models and populations are saved (None: nowhere).
    identify
        False: ingest and window only, never identify (ingestion benchmarks).
    on_generation
        Called by the workers after every generation as ``(stream, progress)``;
        an exception it raises fails that identification like an engine error
        (progress reporting, and the fault-injection tests).
    """

    def __init__(
        self,
        config: DaemonConfig,
        zenoh: ZenohSettings,
        *,
        viz: Any | None = None,
        state_dir: str | Path | None = None,
        identify: bool = True,
        on_generation: Callable[[str, Any], None] | None = None,
    ) -> None:
        self.config = config
        self.zenoh = zenoh
        self.viz = viz
        self.store = StateStore(state_dir) if state_dir is not None else None
        self.bus: Bus | None = None
        self.identify = identify
        self.on_generation = on_generation
        self._streams: dict[str, StreamRuntime] = {}
        self._streams_lock = threading.Lock()
        self._stop = threading.Event()
        self._sched = threading.Condition()
        self._ready: deque[str] = deque()
        self._ready_set: set[str] = set()
        self._threads: list[threading.Thread] = []
        self._helpers: list[EvalHelper | None] = []
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._global: Counter[str] = Counter()
        self._warned: set[str] = set()
        self._started_ns = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Daemon:
        """Open the Zenoh session, restore saved streams, subscribe and start the threads."""
        self._started_ns = time.time_ns()
        if self.config.retain_memory:  # before any thread of ours allocates (see streamid.daemon.memory)
            retain_freed_memory()
        names = list(self.config.streams)
        if self.store is not None:
            for s in self.store.streams():
                if s not in names and (self.config.discover or s in self.config.streams):
                    names.append(s)
        for s in names:
            self._ensure(s)
        n_workers = self.config.workers if self.identify else 0
        self._helpers = [self._start_helper() for _ in range(n_workers)]  # before Zenoh's threads exist
        self.bus = Bus(self.zenoh)
        try:
            if self.config.discover:
                self._subs.append(self.bus.subscribe(f"{PREFIX}/*/*", self._on_sample))
            else:
                for s in self.config.streams:
                    self._subs.append(self.bus.subscribe(f"{PREFIX}/{s}/*", self._on_sample))
            for s in names:
                self._declare(self._streams[s])
        except Exception:
            self.bus.close()
            self._close_helpers()
            raise
        for i in range(n_workers):
            self._spawn(lambda i=i: self._worker_loop(self._helpers[i]), f"streamid-worker-{i}")
        self._spawn(self._housekeeping_loop, "streamid-housekeeping")
        if self.viz is not None:
            for s in names:  # one tab per stream, in the configured order
                self.viz.add_stream(s)
            self.viz.log_event(None, f"daemon started: streams {names or '(discovering)'}")
        _log.info("daemon started; streams %s; discovery %s", names, "on" if self.config.discover else "off")
        return self

    def _start_helper(self) -> EvalHelper | None:
        if not (self.config.helper and EvalHelper.supported()):
            return None
        try:
            return EvalHelper(wait=False)  # the first batches go alone until it runs (~0.15 s)
        except (StreamidError, OSError) as exc:
            _log.warning("no evaluation helper (identification uses one core): %s", exc)
            return None

    def _close_helpers(self) -> None:
        for h in self._helpers:
            if h is not None:
                h.close()
        self._helpers = []

    def _spawn(self, target: Any, name: str) -> None:
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def __enter__(self) -> Daemon:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop within ``timeout_s``: unsubscribe, join threads, save state, close sinks; idempotent."""
        if self._stop.is_set() and self.bus is None:
            return
        deadline = time.monotonic() + timeout_s
        self._stop.set()
        with self._sched:
            self._sched.notify_all()
        for sub in self._subs:
            try:
                sub.close()
            except Exception:  # noqa: BLE001
                pass
        self._subs.clear()
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic() - 0.5))
        alive = [t.name for t in self._threads if t.is_alive()]
        if alive:
            _log.warning("threads still running at shutdown: %s", alive)
        else:
            self._close_helpers()  # (a worker still running keeps its helper; the process exit ends both)
        self._save_all()
        if self.viz is not None:
            self.viz.log_event(None, "daemon stopped")
            self.viz.close(timeout_s=max(0.2, min(1.0, deadline - time.monotonic() - 0.2)))
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until :meth:`stop` was called (or the timeout); returns whether it was."""
        return self._stop.wait(timeout_s)

    def _save_all(self) -> None:
        if self.store is None:
            return
        for rt in list(self._streams.values()):
            with rt.lock:
                if rt.version == 0:
                    continue
                try:
                    self.store.save(rt.snapshot())
                except (OSError, ValueError) as exc:
                    _log.error("stream %s: state not saved at shutdown (%s)", rt.name, exc)

    # ------------------------------------------------------------------ streams
    @property
    def streams(self) -> dict[str, StreamRuntime]:
        """The streams served so far (name -> runtime)."""
        return dict(self._streams)

    def _ensure(self, name: str) -> StreamRuntime | None:
        rt = self._streams.get(name)
        if rt is not None:
            return rt
        with self._streams_lock:
            rt = self._streams.get(name)
            if rt is not None:
                return rt
            if not is_valid_stream_name(name):
                self._global["invalid_stream_names"] += 1
                return None
            if not self.config.discover and name not in self.config.streams:
                return None
            if len(self._streams) >= self.config.max_streams:
                self._global["streams_refused"] += 1
                if "max_streams" not in self._warned:
                    self._warned.add("max_streams")
                    _log.warning("stream %r refused: daemon.max_streams = %d reached", name, self.config.max_streams)
                return None
            rt = StreamRuntime(name, self.config.for_stream(name), notify=lambda n=name: self._wake(n))
            if self.store is not None:
                try:
                    st = self.store.load(name)
                except ModelFormatError as exc:
                    moved = self.store.quarantine(name)
                    _log.error("stream %s: unreadable state (%s); moved to %s, starting cold", name, exc, moved)
                    st = None
                if st is not None:
                    rt.restore(st)
            self._streams[name] = rt
            return rt

    def _declare(self, rt: StreamRuntime) -> None:
        """Publishers and queryables of one stream (housekeeping thread or start)."""
        bus = self.bus
        if rt.declared or bus is None:
            return
        self._pubs[f"{rt.name}/model"] = bus.publisher(model_key(rt.name), block=True)
        self._pubs[f"{rt.name}/status"] = bus.publisher(status_key(rt.name), block=False)
        self._subs.append(bus.queryable(model_key(rt.name), lambda _k, r=rt: r.model_payload))
        self._subs.append(bus.queryable(status_key(rt.name), lambda _k, r=rt: encode_json(r.status(self._daemon_info()))))
        rt.declared = True

    def _daemon_info(self) -> dict[str, Any]:
        return {
            "streams": len(self._streams),
            "uptime_s": round((time.time_ns() - self._started_ns) / 1e9, 3),
            **{k: int(v) for k, v in self._global.items()},
        }

    # ------------------------------------------------------------ receiving path
    def _on_sample(self, key: str, payload: bytes) -> None:
        parts = key.split("/")
        if len(parts) != 3:
            self._global["unknown_keys"] += 1
            return
        _, stream, kind = parts
        if kind not in SAMPLE_KINDS:
            if kind not in _OWN_KINDS:
                rt = self._streams.get(stream)
                if rt is not None:
                    rt.buffer.count_bad("unknown_key", f"key {key!r}: kind must be one of {', '.join(SAMPLE_KINDS)}")
                else:
                    self._global["unknown_keys"] += 1
            return
        rt = self._streams.get(stream) or self._ensure(stream)
        if rt is None:
            return
        try:
            batch = decode(payload)
        except CodecError as exc:
            rt.buffer.count_bad("decode", str(exc)[:300])
            return
        if batch.stream != stream:
            rt.buffer.count_bad("stream_mismatch", f"batch names stream {batch.stream!r} but came on {key!r}")
            return
        rt.buffer.append(batch, source=kind)

    # ------------------------------------------------------------------ workers
    def _wake(self, name: str) -> None:
        with self._sched:
            if name not in self._ready_set:
                self._ready_set.add(name)
                self._ready.append(name)
                self._sched.notify()

    def _next(self) -> StreamRuntime | None:
        with self._sched:
            end = time.monotonic() + 0.2
            while not self._stop.is_set():
                for _ in range(len(self._ready)):
                    name = self._ready.popleft()
                    rt = self._streams.get(name)
                    if rt is None:
                        self._ready_set.discard(name)
                        continue
                    if rt.busy:  # another worker has it; it re-queues when done
                        self._ready.append(name)
                        continue
                    self._ready_set.discard(name)
                    rt.busy = True
                    return rt
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._sched.wait(left)
            return None

    def _worker_loop(self, helper: EvalHelper | None = None) -> None:
        while not self._stop.is_set():
            rt = self._next()
            if rt is None:
                continue
            try:
                self._process(rt, helper)
            except Stopped:
                return
            except Exception:  # noqa: BLE001 - one stream's bug must not stop the others
                _log.error("stream %s: worker error\n%s", rt.name, traceback.format_exc())
            finally:
                with self._sched:
                    rt.busy = False
                if rt.buffer.has_pending:
                    self._wake(rt.name)

    def _process(self, rt: StreamRuntime, helper: EvalHelper | None = None) -> None:
        window = rt.buffer.take()
        if window is None:
            return
        try:
            out = identify_window(
                window,
                rt.cfg,
                version=rt.version + 1,
                warm_state=rt.coea_state,
                warm_signature=rt.signature,
                force_cold=rt.force_cold,
                stop=self._stop,
                on_generation=self.on_generation,
                helper=helper,
            )
        except Stopped:
            raise
        except Exception as exc:  # noqa: BLE001 - an engine bug is a failed update, not a dead daemon
            _log.error("stream %s: identification raised\n%s", rt.name, traceback.format_exc())
            out = Outcome("failed", f"identification raised {type(exc).__name__}: {exc}", "exception")
        published = rt.apply(window, out, self.store)
        latency_s = None
        if published is not None:
            pub = self._pubs.get(f"{rt.name}/model")
            if pub is None:
                self._declare(rt)
                pub = self._pubs.get(f"{rt.name}/model")
            if pub is not None:
                pub.put(published.payload)
            latency_s = (time.monotonic_ns() - window.closed_monotonic_ns) / 1e9
            with rt.lock:
                rt.last["latency_s"] = latency_s
                rt.recent_latencies.append((published.version, latency_s))
        elif out.kind != "accepted":
            _log.info("stream %s: window %d %s: %s", rt.name, window.number, out.kind, out.reason)
        if self.viz is not None:
            self._draw(rt, window, out, published.version if published else rt.version, latency_s)

    def _draw(self, rt: StreamRuntime, window: Any, out: Outcome, version: int, latency_s: float | None) -> None:
        from streamid.daemon.report import update_report  # viz types only when drawing

        self.viz.add_stream(rt.name)  # idempotent: a discovered stream gets its tab at its first update
        if out.summary is None:
            self.viz.log_event(rt.name, f"window {window.number} {out.kind}: {out.reason}", level="WARN",
                               t_ns=window.t_end_ns)
            return
        self.viz.log_update(update_report(rt.name, window, out, version, latency_s))

    # -------------------------------------------------------------- housekeeping
    def _housekeeping_loop(self) -> None:
        next_status = 0.0
        every = self.config.status_every_s
        while not self._stop.wait(0.05):
            for rt in list(self._streams.values()):
                if not rt.declared:
                    try:
                        self._declare(rt)
                    except Exception as exc:  # noqa: BLE001
                        _log.error("stream %s: declarations failed (%s)", rt.name, exc)
                self._forward_events(rt)
            now = time.monotonic()
            if now >= next_status:
                next_status = now + every
                self.publish_status()

    def publish_status(self) -> None:
        """Put the status of every stream on its status key."""
        info = self._daemon_info()
        for rt in list(self._streams.values()):
            pub = self._pubs.get(f"{rt.name}/status")
            if pub is None:
                continue
            try:
                pub.put(encode_json(rt.status(info)))
            except Exception as exc:  # noqa: BLE001
                _log.debug("status of %s not published: %s", rt.name, exc)

    def _forward_events(self, rt: StreamRuntime) -> None:
        events = rt.buffer.drain_events()
        if not events:
            return
        for ev in events[-20:]:
            _log.info("%s", ev.message)
        if self.viz is not None:
            last_t = rt.buffer.counters().get("last_t_ns")
            for ev in events[-20:]:
                level = "WARN" if ev.kind.startswith(("bad", "reset", "gap", "unaligned")) else "INFO"
                self.viz.log_event(rt.name, ev.message, level=level, t_ns=last_t if isinstance(last_t, int) else None)
            if len(events) > 20:
                self.viz.log_event(rt.name, f"... and {len(events) - 20} more events", level="WARN")
