"""The daemon's worker threads: which job runs when, and how long it may run.

:class:`JobRunner` takes jobs from the :class:`~streamid.daemon.scheduler.Scheduler`
(oldest waiting stream first), runs each under a :class:`~streamid.daemon.admission.Deadline`
(``daemon.max_identification_s`` of its own time; past it the run stops between two
generations and becomes a failed update, ``code = "timeout"``, counted), refuses a
window whose identification would need more than ``daemon.max_identification_bytes``
(a dropped update, ``code = "too_large"``), and between two generations of a long
run lets other streams' short jobs run to their end on the same thread (see
:mod:`streamid.daemon.scheduler`).  A refresh of a champion's weights
(:mod:`streamid.online.refresh`) is always short (:data:`REFRESH_EXPECTED_S`) and never refused
for the memory bound: it holds a window's design rows of one network, not a population's.  What becomes of an outcome (judging, saving,
publishing, drawing) is the daemon's ``finish`` callback.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any, Literal

from streamid.daemon.admission import Deadline, identification_bytes
from streamid.daemon.config import DaemonConfig
from streamid.daemon.scheduler import NESTED_SHARE, SLICE_S, Scheduler
from streamid.daemon.slots import StreamSlot
from streamid.engine.search.parallel import EvalHelper
from streamid.online import Outcome, Stopped, UpdateJob
from streamid.online.refresh import RefreshJob

__all__ = ["JobRunner"]

_log = logging.getLogger("streamid.daemon.service")

#: A stream's first run while other streams wait for theirs runs this share of its ``cold_generations`` (every
#: stream served sooner; its usual warm runs go on from the populations). Measured on 2 kHz MR damper windows
#: (docs/benchmarks.md): 200 of 400 generations, 0.51 s instead of 0.80 s, held-out FR R^2 median 0.935 / 0.934.
FIRST_RUN_SHARE = 0.5

#: What the scheduler expects a refresh to take (measured: 2-8 ms for 10 s windows at 200 Hz-2 kHz): a short job.
REFRESH_EXPECTED_S = 0.01

Finish = Callable[[StreamSlot, UpdateJob, Outcome], None]
Taken = tuple[StreamSlot, UpdateJob]


class JobRunner:
    """Runs the streams' jobs on the calling worker threads (see the module docstring).

    Parameters
    ----------
    streams
        The daemon's live ``name -> slot`` mapping (read only).
    config
        The daemon's configuration (the bounds).
    stop
        The daemon's stop flag.
    counters
        The daemon's counters (``identification_timeouts`` is added to them).
    finish
        ``finish(slot, job, outcome)``: judge, save, publish, draw (called on the worker thread).
    on_generation
        The user's per-generation hook (its exception fails that run).
    """

    def __init__(self, streams: Mapping[str, StreamSlot], config: DaemonConfig, stop: threading.Event,
                 counters: Counter[str], finish: Finish,
                 on_generation: Callable[[str, Any], None] | None = None) -> None:
        self.streams = streams
        self.config = config
        self.stop = stop
        self.counters = counters
        self.finish = finish
        self.on_generation = on_generation
        self.scheduler: Scheduler[Taken] = Scheduler()

    def wake(self, name: str) -> None:
        """``name`` has a window due."""
        self.scheduler.wake(name)

    def worker_loop(self, helper: EvalHelper | None = None) -> None:
        """Serve jobs until the daemon stops (the body of a worker thread)."""
        while not self.stop.is_set():
            nxt = self.scheduler.take(self._try_take, self.stop, first=self._first_run)
            if nxt is None:
                continue
            st, job = nxt
            try:
                self._serve(st, job, helper, nested=False)
            except Stopped:
                return

    def _try_take(self, name: str, *, loaded: bool = False) -> Taken | None | Literal[False]:
        """The stream's next job; None: nothing due; False: busy (the scheduler's lock is held).

        While other streams wait for a worker (or ``loaded``: a long run is going on), a coevolution run due only
        by its schedule is deferred and the champion refreshed instead (:mod:`streamid.online.refresh`). A stream's
        first run while others wait for theirs runs :data:`FIRST_RUN_SHARE` of its cold generations.
        """
        st = self.streams.get(name)
        if st is None:
            return None
        loaded = loaded or self.scheduler.waiting() > 1
        with st.lock:
            if st.ident.busy:
                return False
            first = st.ident.first_run_due
        gens = None  # (the other streams' locks are taken outside this one's)
        if first and self.scheduler.any_waiting(lambda n: n != name and self._first_run(n)):
            gens = max(1, round(FIRST_RUN_SHARE * st.ident.config.cold_generations))
        with st.lock:
            if st.ident.busy:
                return False
            job = st.ident.next_job(defer_scheduled=loaded, first_generations=gens)
        return None if job is None else (st, job)

    def _first_run(self, name: str) -> bool:
        """Whether the stream's next job is its first (no update finished yet): taken first (the scheduler's lock
        is held: the same order as _try_take)."""
        st = self.streams.get(name)
        if st is None:
            return False
        with st.lock:
            return st.ident.first_run_due

    def _expected_s(self, name: str) -> float | None:
        """Expected seconds of the stream's next job (None: unknown)."""
        st, spg = self.streams.get(name), self.scheduler.sec_per_generation(name)
        if st is None:
            return None
        with st.lock:  # (the scheduler's lock is held: the same order as _try_take)
            if st.ident.next_is_refresh(defer_scheduled=True):  # (asked only while a long run goes on)
                return REFRESH_EXPECTED_S
        if spg is None:
            return None
        cfg = st.ident.config
        return spg * (cfg.warm_generations if st.ident.version > 0 else cfg.cold_generations)

    def _serve(self, st: StreamSlot, job: UpdateJob, helper: EvalHelper | None, *, nested: bool) -> None:
        """Run one job to its end (Stopped only when the daemon stops), then requeue the stream if more is due."""
        try:
            self.finish(st, job, self._run(st, job, helper, nested))
        except Stopped:
            raise
        except Exception:  # noqa: BLE001 - one stream's bug must not stop the others
            _log.error("stream %s: worker error\n%s", st.ident.stream, traceback.format_exc())
        finally:
            with st.lock:
                st.ident.abandon(job)  # (a no-op when finished)
                again = st.ident.pending > 0
            if again:
                self.scheduler.wake(st.ident.stream)

    def _too_large(self, st: StreamSlot, job: UpdateJob) -> Outcome | None:
        if isinstance(job, RefreshJob):
            return None
        w, cfg = job.window, st.ident.config
        need = identification_bytes(w.n, len(w.input_names), len(w.output_names), cfg)
        if need <= self.config.max_identification_bytes:
            return None
        return Outcome("dropped", f"identifying {w.n} samples x {len(w.input_names)} inputs needs ~{need >> 20} MiB; "
                       f"daemon.max_identification_bytes is {self.config.max_identification_bytes >> 20} MiB",
                       "too_large")

    def _run(self, st: StreamSlot, job: UpdateJob, helper: EvalHelper | None, nested: bool) -> Outcome:
        name = st.ident.stream
        deadline = Deadline(self.stop, self.config.max_identification_s)
        gens = [0]

        def hook(stream: str, progress: Any) -> None:
            gens[0] += 1
            if self.on_generation is not None:
                self.on_generation(stream, progress)
            if not nested and deadline.own_s >= SLICE_S:
                self._let_short_jobs_in(st, deadline)

        out = self._too_large(st, job)
        try:
            if out is None:
                out = job.run(stop=deadline, on_generation=hook, helper=helper)
        except Stopped:
            if self.stop.is_set():
                raise
            st.identification_timeouts += 1
            self.counters["identification_timeouts"] += 1
            out = Outcome("failed", f"identification stopped after {deadline.own_s:.1f} s ({gens[0]} generations): "
                          f"longer than daemon.max_identification_s = {self.config.max_identification_s:g} s",
                          "timeout", seconds=deadline.own_s)
        except Exception as exc:  # noqa: BLE001 - an engine bug is a failed update, not a dead daemon
            _log.error("stream %s: identification raised\n%s", name, traceback.format_exc())
            out = Outcome("failed", f"identification raised {type(exc).__name__}: {exc}", "exception")
        self.scheduler.record(name, deadline.own_s, gens[0])
        return out

    def _let_short_jobs_in(self, st: StreamSlot, deadline: Deadline) -> None:
        """Between two generations of ``st``'s run: run other streams' short jobs to their end (none while a
        stream waits for its first run: first runs go before the served streams' next jobs, see the scheduler)."""
        for _ in range(max(1, len(self.streams))):  # each waiting stream at most once per generation
            if deadline.paused_s > NESTED_SHARE * deadline.own_s:  # the long run keeps its share of the worker
                return
            if self.scheduler.any_waiting(self._first_run):
                return
            nxt = self.scheduler.take_short(lambda n: self._try_take(n, loaded=True), self._expected_s,
                                            exclude=st.ident.stream)
            if nxt is None:
                return
            other, job = nxt
            t0 = time.monotonic()
            try:
                other.nested_runs += 1
                self._serve(other, job, None, nested=True)  # (the helper stays bound to the long run's data)
            finally:
                deadline.pause(time.monotonic() - t0)
