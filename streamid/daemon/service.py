"""The identification daemon: the adapter between Zenoh, threads, disk, Rerun and :class:`OnlineIdentifier`.

Every stream is one :class:`~streamid.online.OnlineIdentifier` (the streaming core:
window, checks, pending queue, warm/cold policy, acceptance, versions) behind a
lock.  The daemon only moves things in and out of it:

* **Zenoh's callback threads** split the key, :func:`streamid.wire.codec.decode`
  the payload and :meth:`~OnlineIdentifier.push` the batch (with the receive time).
  A closed window wakes a worker.
* **Worker threads** (``daemon.workers``, default 2) take the stream whose window
  waited longest, a stream's first run before the others (:mod:`streamid.daemon.scheduler`:
  short jobs of other streams also run between the generations of a long one), :meth:`~OnlineIdentifier.next_job`, run the job
  outside the lock (samples keep arriving meanwhile),
  :meth:`~OnlineIdentifier.finish` it -- the new state is saved to ``--state-dir``
  *before* an accepted model is handed out, so a version is never reused after a
  crash -- publish the model, and only then draw the update in Rerun.  Each worker
  owns an :class:`~streamid.engine.search.parallel.EvalHelper` (``daemon.helper``): a fresh
  ``python -m`` process, started before the Zenoh session, sharing memory with the
  worker, that evaluates half of every population batch on otherwise idle CPU
  (SCHED_IDLE: it never takes a core from ingestion).  A helper that fails to start
  is reported once and the worker goes on alone.
* **One housekeeping thread** declares the per-stream publishers and queryables,
  publishes status every ``status_every_s`` and forwards the streams' events (gaps,
  resets, bad input: logged, at most one line per kind and stream every 10 s) to the
  log and to the Rerun event log.

What a remote party can make the daemon spend is bounded (:mod:`streamid.daemon.admission`):
payload size (checked before decoding), channels per batch, one stream's buffers
plus one identification's memory, one identification's time, and stream slots
(a discovered stream without a valid sample for ``stream_idle_s`` gives its slot
back).  Every refusal is counted on the stream's or the daemon's status.

Lock order: the scheduler's condition, then a stream's lock; no thread holds a
stream's lock while it waits for anything else.

:meth:`Daemon.stop` sets a stop flag seen between two generations, undeclares
the subscriptions, joins the threads, saves the state and closes the Rerun
sinks (the ``.rrd`` footer is written) within the given deadline.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from streamid.wire.codec import SampleBatch, decode
from streamid.daemon.config import DaemonConfig
from streamid.wire.documents import encode_json
from streamid.daemon.admission import STREAM_FAULTS, check_batch, known_channels
from streamid.daemon.memory import LARGE_PAYLOAD, give_back_freed_memory, retain_freed_memory
from streamid.daemon.runner import JobRunner
from streamid.daemon.slots import StreamSlot as _Stream
from streamid.daemon.slot_keeping import SlotKeeping
from streamid.daemon.slots import EVICT_GRACE_S, evictable, forward_events
from streamid.daemon.state_store import StateStore
from streamid.daemon.identity import daemon_origin
from streamid.daemon.intake_budget import IntakeBudget
from streamid.daemon.ros2_intake import Ros2Intake, subscribe_ros2
from streamid.daemon.share_link import ShareLink
from streamid.daemon.sharing import Life, Shares
from streamid.daemon.versions import VersionKeeper
from streamid.online import OnlineIdentifier, Outcome, Update, UpdateJob
from streamid.online.refresh import RefreshOutcome
from streamid.engine import warm_up_kernels
from streamid.engine.search.parallel import EvalHelper
from streamid.errors import CodecError, StreamidError
from streamid.wire.keys import PREFIX, SAMPLE_KINDS, is_valid_stream_name
from streamid.transport import Bus, ZenohSettings

__all__ = ["Daemon"]

_log = logging.getLogger(__name__)
_OWN_KINDS = ("model", "status", "rejected")
#: Zenoh drops a received message larger than this many times ``max_payload_bytes`` before reassembling it.
ZENOH_MESSAGE_FACTOR = 8


class Daemon(SlotKeeping):
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
        self.versions = VersionKeeper(self.store, daemon_origin(state_dir))  # origin, lost-state and full-disk rules
        self.bus: Bus | None = None
        self.identify = identify
        self.on_generation = on_generation
        self._streams: dict[str, _Stream] = {}
        self._streams_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._helpers: list[EvalHelper | None] = []
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._global: Counter[str] = Counter()
        self._warned: set[str] = set()
        self._started_ns = 0
        self._large_payload = threading.Event()  # a large payload came in: give heap memory back
        self._released: deque[_Stream] = deque()  # slots taken by new streams, declarations still to close
        self._runner = JobRunner(self._streams, config, self._stop, self._global, self._finish, on_generation)
        origin = self.versions.origin  # who serves which stream (streamid.daemon.sharing)
        self.shares = Shares(Life(origin.daemon, origin.epoch_ns), share=config.share and config.discover,
                             explicit=config.streams, settle_ns=int(config.claim_settle_s * 1e9))
        self.link = ShareLink(self.shares, join_after_s=config.join_after_s, max_streams=config.max_streams,
                              max_payload_bytes=config.max_payload_bytes)
        self._budget = IntakeBudget(config.max_batches_per_s)  # fair intake: checked before decoding
        self._ros2: dict[str, Ros2Intake] = {}  # stream -> its ROS 2 topics (streamid.daemon.ros2_intake)

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
        if n_workers:  # the compiled free run is loaded (or, the first time on a machine, compiled) before any decision
            warm_up_kernels()
        self._helpers = [self._start_helper() for _ in range(n_workers)]  # before Zenoh's threads exist
        limit = self.config.max_payload_bytes
        self.bus = Bus(self.zenoh.with_max_message_bytes(min(1 << 30, max(ZENOH_MESSAGE_FACTOR * limit, 1 << 20))),
                       stop=self._stop)  # a client waiting for its router gives up when stopped
        try:
            keys = [f"{PREFIX}/*/*"] if self.config.discover else [f"{PREFIX}/{s}/*" for s in self.config.streams]
            for key in keys:
                self._subs.append(self.bus.subscribe(key, self._on_sample, max_payload_bytes=limit,
                                                     on_too_large=self._on_too_large))
            self._ros2 = subscribe_ros2(self.bus, self.config, self._subs, self._ros2_take, self._ros2_bad,
                                        self._ros2_admit)  # [streams.X.ros2]: ROS 2 topics, gridded, into _take
            self.link.start(self.bus)  # a stream's publishers are declared once it is served (housekeeping)
        except Exception:
            self.bus.close()
            self._close_helpers()
            raise
        for i in range(n_workers):
            self._spawn(lambda i=i: self._runner.worker_loop(self._helpers[i]), f"streamid-worker-{i}")
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
        if self._stop.is_set() and self.bus is None and not self._threads:
            return
        deadline = time.monotonic() + timeout_s
        self._stop.set()
        self._runner.scheduler.notify_all()
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
        self.link.close()
        if self.viz is not None:
            self.viz.log_event(None, "daemon stopped")
            self.viz.close(timeout_s=max(0.2, min(1.0, deadline - time.monotonic() - 0.2)))
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    def request_stop(self) -> None:
        """Ask a running (or starting) daemon to stop; safe from a signal handler. :meth:`stop` does the work."""
        self._stop.set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until :meth:`stop` was called (or the timeout); returns whether it was."""
        return self._stop.wait(timeout_s)

    def _save_all(self) -> None:
        if self.store is None:
            return
        for st in list(self._streams.values()):
            with st.lock:
                if st.ident.version == 0:
                    continue
                try:
                    self.store.save(st.ident.state(now_ns=time.time_ns()))
                except (OSError, ValueError) as exc:
                    _log.error("stream %s: state not saved at shutdown (%s)", st.ident.stream, exc)

    # ------------------------------------------------------------------ streams
    @property
    def streams(self) -> tuple[str, ...]:
        """Names of the streams served so far."""
        return tuple(self._streams)

    def stream_status(self, name: str) -> dict[str, Any] | None:
        """The status document of one stream, as published (None: not served)."""
        st = self._streams.get(name)
        return None if st is None else self._status(st)

    def latencies(self, name: str) -> list[tuple[int, float]]:
        """(version, seconds from window closed to model published) of the stream's recent updates."""
        st = self._streams.get(name)
        if st is None:
            return []
        with st.lock:
            return list(st.recent_latencies)

    def update_latencies(self, name: str) -> list[tuple[float, str, float]]:
        """(monotonic time, kind, seconds from window closed to decided) of the stream's recent updates, every kind."""
        st = self._streams.get(name)
        if st is None:
            return []
        with st.lock:
            return list(st.recent_updates)

    def _ensure(self, name: str) -> _Stream | None:
        st = self._streams.get(name)
        if st is not None:
            return st
        with self._streams_lock:
            st = self._streams.get(name)
            if st is not None:
                return st
            if not is_valid_stream_name(name):
                self._global["invalid_stream_names"] += 1
                return None
            if not self.config.discover and name not in self.config.streams:
                return None
            victim = None
            if len(self._streams) >= self.config.max_streams:  # a slot that only ever had bad input goes first
                victim = evictable(self._streams.values(), time.monotonic(), min(EVICT_GRACE_S, self.config.stream_idle_s))
                if victim is not None:
                    del self._streams[victim.ident.stream]
                    self._global["streams_released"] += 1
                    self._released.append(victim)  # its declarations are closed by the housekeeping thread
            if len(self._streams) >= self.config.max_streams:
                self._global["streams_refused"] += 1
                if "max_streams" not in self._warned:
                    self._warned.add("max_streams")
                    _log.warning("stream %r refused: daemon.max_streams = %d reached", name, self.config.max_streams)
                return None
            ident = OnlineIdentifier(self.config.for_stream(name), stream=name, origin=self.versions.origin_doc)
            self.versions.resume(ident)  # saved state; a damaged file quarantined, its version recovered
            st = self._streams[name] = _Stream(ident, configured=name in self.config.streams)
            _log.info("stream %s: %s", name, "configured" if name in self.config.streams else "discovered")
            return st

    def _daemon_info(self) -> dict[str, Any]:
        return {
            "streams": len(self._streams),
            "uptime_s": round((time.time_ns() - self._started_ns) / 1e9, 3),
            "origin": self.versions.origin_doc,  # who publishes this life's models (daemon id, epoch)
            "sharing": self.link.info(),  # members, streams served here
            **{k: int(v) for k, v in self._global.items()},
        }

    def _status(self, st: _Stream) -> dict[str, Any]:
        with st.lock:
            doc = st.ident.status(now_ns=time.time_ns())
            if st.latency_s is not None:
                doc["last"]["latency_s"] = st.latency_s
            doc.update(st.counters())
        if (ros2 := self._ros2.get(st.ident.stream)) is not None:
            doc["ros2"] = ros2.status()
        doc["daemon"] = self._daemon_info()
        return doc

    # ------------------------------------------------------------ receiving path
    def _on_too_large(self, key: str, size: int) -> None:
        """A payload over ``max_payload_bytes``: refused undecoded, counted on its stream (or the daemon)."""
        self._large_payload.set()
        parts = key.split("/")
        st = self._streams.get(parts[1]) if len(parts) == 3 else None
        if st is None:
            self._global["payloads_too_large"] += 1
            return
        with st.lock:
            st.ident.count_bad("too_large", f"payload of {size} bytes on {key!r}; daemon.max_payload_bytes is "
                               f"{self.config.max_payload_bytes} (send smaller batches, or raise it)",
                               now_ns=time.time_ns())

    def _on_sample(self, key: str, payload: bytes) -> None:
        parts = key.split("/")
        if len(parts) != 3:
            self._global["unknown_keys"] += 1
            return
        _, stream, kind = parts
        if kind not in SAMPLE_KINDS:
            if kind not in _OWN_KINDS:
                known = self._streams.get(stream)
                if known is not None:
                    with known.lock:
                        known.ident.count_bad("unknown_key", f"key {key!r}: kind must be one of {', '.join(SAMPLE_KINDS)}",
                                              now_ns=time.time_ns())
                else:
                    self._global["unknown_keys"] += 1
            return
        if self.shares.role(stream) == "none":  # another daemon serves it, and another stands by
            self._global["batches_for_others"] += 1
            return
        st = self._streams.get(stream) or self._ensure(stream)
        if st is None:
            return
        if not self._budget.admit(stream):  # over its share of the intake budget: dropped undecoded, counted
            self._global["intake_dropped"] += 1
            with st.lock:
                st.intake_dropped += 1
                first = st.intake_dropped == 1
            if first:
                _log.warning("stream %s: batches dropped before decoding: over its share of daemon.max_batches_per_s "
                             "= %d, shared by the streams sending (counted as intake_dropped on its status; not "
                             "repeated)", stream, self.config.max_batches_per_s)
            return
        if len(payload) >= LARGE_PAYLOAD:
            self._large_payload.set()
        now_ns = time.time_ns()
        try:
            batch = decode(payload)
        except CodecError as exc:
            with st.lock:
                st.ident.count_bad("decode", str(exc)[:300], now_ns=now_ns)
            return
        del payload
        self._take(st, stream, kind, batch, now_ns)

    def _take(self, st: _Stream, stream: str, kind: str, batch: SampleBatch, now_ns: int) -> None:
        """A decoded batch into its stream: streamid's own keys and ROS 2 topics (:mod:`streamid.daemon.ros2_intake`)."""
        with st.lock:
            if batch.stream != stream:
                st.ident.count_bad("stream_mismatch", f"batch names stream {batch.stream!r} but came on {f'{PREFIX}/{stream}/{kind}'!r}",
                                   now_ns=now_ns)
                return
            refused = check_batch(batch, st.ident.config, max_channels=self.config.max_channels,
                                  max_bytes=self.config.max_identification_bytes,
                                  known=known_channels(st.ident.counters()))
            if refused is not None:
                st.ident.count_bad(refused[0], refused[1], now_ns=now_ns)
                if refused[0] in STREAM_FAULTS:  # every batch as sent would be: the stream is degraded, never ok
                    st.ident.intake_fault(f"cannot be identified as sent: {refused[1]}")
                return
            st.ident.intake_fault("")
            events = st.ident.push(batch, source=kind, now_ns=now_ns)
            if not st.had_valid and not any(ev.kind.startswith("bad.") for ev in events):
                st.had_valid = True
            due = st.ident.pending > 0
            if due and not self.shares.serving(stream):
                if not self.shares.keeps_windows(stream):
                    st.ident.skip_pending()  # a standby keeps the window, never identifies
                due = False  # (a claimed stream's windows wait until it is served)
        if due and self.identify:
            self._runner.wake(stream)

    def _ros2_admit(self, stream: str) -> bool:
        """Whether one ROS 2 message of ``stream`` is taken: served here, and within its intake budget share."""
        st = self._streams.get(stream)
        if st is None or self.shares.role(stream) == "none":
            return False
        if self._budget.admit(stream):
            return True
        self._global["intake_dropped"] += 1
        with st.lock:
            st.intake_dropped += 1
        return False

    def _ros2_take(self, batch: SampleBatch) -> None:
        if (st := self._streams.get(batch.stream)) is not None:
            self._take(st, batch.stream, "samples", batch, time.time_ns())

    def _ros2_bad(self, stream: str, kind: str, message: str) -> None:
        if (st := self._streams.get(stream)) is not None:
            with st.lock:
                st.ident.count_bad(kind, message, now_ns=time.time_ns())

    # ------------------------------------------------------------------ results
    def _finish(self, st: _Stream, job: UpdateJob, out: Outcome) -> None:
        """Judge a job's outcome, save, publish an accepted model, then draw it (a worker thread)."""
        name, window = st.ident.stream, job.window
        if not self.shares.serving(name):
            self._global["results_handed_over"] += 1  # served elsewhere since the job began: not ours to publish
            return
        # versions leave in the order they are given: a job of this stream that finishes meanwhile (a worker may
        # stall between its version and its put) waits here, so subscribers never see v8 before v7
        with st.publish_order:
            persist = self.versions.persist if self.store is not None else None
            self.versions.settle(st.ident, self.bus, st.lock)  # once per stream without state: the network's version
            with st.lock:
                up = st.ident.finish(job, out, now_ns=time.time_ns(), persist=persist)
                # the state for a successor (~2 ms and ~100 kB for the MR damper): only when there may be one
                state = st.ident.state(now_ns=time.time_ns()).to_json() if self.link.has_successor() else None
            latency_s = None
            with st.lock:
                st.recent_updates.append((time.monotonic(), up.kind, (time.time_ns() - window.received_ns) / 1e9))
            with self.shares.publish_lock:  # a release waits for this put to end; no put after it
                if not self.shares.serving(name):
                    self._global["results_handed_over"] += 1
                    return
                if state is not None:
                    self.link.hand_off(name, state)  # before the model: the next owner never reuses its version
                if up.kind == "rejected" and up.payload is not None and (rej := self._pubs.get(f"{name}/rejected")):
                    rej.put(up.payload)  # a rejected challenger, for subscribers that asked (include_rejected)
                if up.accepted and up.payload is not None and (pub := self._pubs.get(f"{name}/model")) is not None:
                    pub.put(up.payload)
        if up.accepted:
            latency_s = (time.time_ns() - window.received_ns) / 1e9
            with st.lock:
                st.latency_s = latency_s
                st.recent_latencies.append((up.version, latency_s))
            m = up.metrics
            _log.info("stream %s: window %d identified, model v%d published (%s, R² validation OSA %.4f FR %.4f, "
                      "%.2f s, latency %.2f s)", name, window.number, up.version,
                      "refreshed" if isinstance(out, RefreshOutcome) else "warm" if out.warm else "cold",
                      m.get("r2_osa_val", float("nan")), m.get("r2_fr_val", float("nan")), out.seconds, latency_s)
        else:
            _log.info("stream %s: window %d %s, model v%d kept: %s", name, window.number, up.kind, up.version, up.reason)
        if self.viz is not None:
            self._draw(name, up, latency_s)

    def _draw(self, name: str, up: Update, latency_s: float | None) -> None:
        from streamid.daemon.report import update_report  # viz types only when drawing

        assert self.viz is not None
        view = f"{name}/{up.output}" if len(up.window.output_names) > 1 and up.output else name  # a tab per output
        self.viz.add_stream(view)  # idempotent: a discovered stream gets its tab at its first update
        if up.outcome.summary is None:
            self.viz.log_event(view, f"window {up.window.number} {up.kind}: {up.reason}", level="WARN",
                               t_ns=up.window.t_end_ns)
            return
        self.viz.log_update(update_report(view, up, latency_s))

    # -------------------------------------------------------------- housekeeping
    def _housekeeping_loop(self) -> None:
        next_status = next_idle = next_trim = 0.0
        every = self.config.status_every_s
        while not self._stop.wait(0.05):
            self.link.tick(list(self._streams), self._serve, self._release)
            for st in list(self._streams.values()):
                forward_events(st, self.viz)
            now = time.monotonic()
            if now >= next_status:
                next_status = now + every
                self.publish_status()
            if now >= next_idle:
                next_idle = now + min(1.0, self.config.stream_idle_s / 4)
                self._release_idle(now)
            while self._released:
                self._close_slot(self._released.popleft(), "taken by a new stream: it never had a valid batch")
            if now >= next_trim and self._large_payload.is_set():
                next_trim = now + 1.0
                self._large_payload.clear()
                give_back_freed_memory()

    def publish_status(self) -> None:
        """Put the status of every stream on its status key."""
        for st in list(self._streams.values()):
            pub = self._pubs.get(f"{st.ident.stream}/status")
            if pub is None:
                continue
            try:
                pub.put(encode_json(self._status(st)))
            except Exception as exc:  # noqa: BLE001
                _log.debug("status of %s not published: %s", st.ident.stream, exc)
