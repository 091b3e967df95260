"""``OnlineIdentifier``: online identification of one stream, with no threads, no I/O and no clock.

In the manner of river's streaming learners, samples go in (:meth:`~OnlineIdentifier.push`
a :class:`~streamid.wire.codec.SampleBatch`, or :meth:`~OnlineIdentifier.learn_many` /
:meth:`~OnlineIdentifier.learn_one` with numpy arrays) and the current model comes out
(:meth:`~OnlineIdentifier.predict_one`, :meth:`~OnlineIdentifier.simulate`).  The
identifier owns everything between: the bounded window buffer with its gap, reset and
period checks (:mod:`streamid.online.window`), the bounded queue of closed windows
(:mod:`streamid.online.pending`), the warm/cold policy, the acceptance of a new model,
and version numbers.

Identification never happens behind the caller's back.  A closed window waits until the
caller runs :meth:`~OnlineIdentifier.update` (one pending window) or
:meth:`~OnlineIdentifier.update_all` (all of them, oldest first).  A caller that wants the
identification on another thread -- the daemon -- splits it in three:
:meth:`~OnlineIdentifier.next_job` (fast: takes the window and freezes what the run needs
into an :class:`~streamid.online.update.UpdateJob`), :meth:`UpdateJob.run
<streamid.online.update.UpdateJob.run>` (slow, pure: touches no identifier state) and
:meth:`~OnlineIdentifier.finish` (fast: judges the candidate, numbers the version).  At most
one job is out at a time: each warm start continues the previous run.

**Champion and challenger.**  Each modelled output (every output of the stream, or
``config.output``) has a served model, its *champion*.  An update's candidate, the
*challenger*, and the champion are evaluated on the same held-out newest part of the
window; the challenger becomes the champion, with the next version of the stream, only by
the rule of :mod:`streamid.online.acceptance` (valid, and better by ``challenger_margin``
or the champion no longer valid on current data).  Otherwise the update is *rejected*
(``code`` says why: ``not_better`` keeps a good champion, ``validation`` a challenger below
the floors), *failed* (the engine raised) or *dropped* (the window cannot be identified:
too short, constant signal, missing output) and the champion stays.  After
``cold_after_failures`` failed or invalid updates in a row the next run starts cold; a run
whose signals, period or search size differ from the populations' starts cold too.

**Drift.**  Between updates, every block of samples pushed is run through the champion in a
short free run and the output's level relative to it watched by a CUSUM test
(:mod:`streamid.online.drift`).  A ``drift`` event then makes the next identification of
that output use only the data from the estimated change on, with ``drift_generations``.

Everything that happens comes back as a value: :meth:`push` returns the
:class:`~streamid.online.window_types.Event` s it raised (gap, reset, refused batch, window
closed or coalesced), :meth:`finish` an :class:`Update` that carries its own event; the
newest 256 events are also kept for :meth:`drain_events`.  Times the caller wants recorded
(when a batch arrived, when a model was published) are passed in as ``now_ns``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from streamid.engine import EvalHelper
from streamid.model import Model
from streamid.errors import ConfigError, ModelFormatError
from streamid.online.acceptance import Decision, Update, decide, degraded_after
from streamid.online.drift import DriftSettings, reference_monitor
from streamid.online.champions import ChampionViews
from streamid.online.head import OutputHead, restored_head
from streamid.online.health import Health
from streamid.online.intake import EVENTS_KEPT, StreamIntake
from streamid.online.refresh import RefreshJob, RefreshPolicy, RefreshTrack, coevolve_reason, refresh_job
from streamid.online.snapshot import StreamState
from streamid.online.status import stream_status
from streamid.online.stream_config import StreamConfig
from streamid.online.update import Outcome, StopFlag, UpdateJob, cut_window
from streamid.online.watch import watch_blocks
from streamid.online.window_types import Window
from streamid.wire.documents import MAX_VERSION, encode_json, model_update_message
from streamid.wire.keys import check_stream_name

__all__ = ["OnlineIdentifier", "Update", "Persist", "EVENTS_KEPT"]

#: Called by :meth:`OnlineIdentifier.finish` with the state after an accepted update, before it is
#: returned.  If it raises (``OSError``, ``ValueError``, ``ModelFormatError``) the update still stands
#: (``Update.saved`` is False, the status says ``state_saved: false``): versions stay unique in memory.
Persist = Callable[[StreamState], object]

#: After a drift, identifications run with ``drift_generations`` until a challenger is accepted, at most this many.
ESCALATED_RUNS = 3

#: A windows' cut after a drift is used only if it keeps at least this fraction of the window.
_MIN_CUT_FRACTION = 0.25


class OnlineIdentifier(StreamIntake, ChampionViews):
    """Online identification of one stream (single-threaded; see the module docstring).

    Parameters
    ----------
    config
        The stream's settings (default: :class:`StreamConfig` defaults: 10 s windows,
        an update every second).
    stream
        The stream's name (``[A-Za-z0-9_.-]{1,128}``), used in windows, events and documents.
    origin
        Who publishes the documents (e.g. ``{"daemon": "...", "epoch_ns": ...}``): copied into each
        model-update document so a subscriber recognises a restarted or another publisher.
    refresh
        When updates refresh the champion's weights instead of rerunning the coevolution
        (:mod:`streamid.online.refresh`; default: the config's ``refresh``, :class:`~streamid.online.refresh_policy.RefreshPolicy`,
        ``RefreshPolicy(enabled=False)``: every update is a coevolution run).

    Examples
    --------
    >>> from streamid import OnlineIdentifier, StreamConfig
    >>> from streamid.sim import get_device
    >>> t_ns, u, y = get_device("mr_damper").simulate_seconds(12.0, seed=1)
    >>> cfg = StreamConfig(window_s=4.0, update_every_s=4.0, cold_generations=60, max_pending_windows=8)
    >>> ident = OnlineIdentifier(cfg, stream="damper")
    >>> events = ident.learn_many(t_ns, u, y, inputs=["velocity_cm_s"], outputs=["force_N"])
    >>> [(up.kind, up.version) for up in ident.update_all()]  # doctest: +SKIP
    [('accepted', 1), ('rejected', 1), ('accepted', 2)]
    """

    def __init__(
        self, config: StreamConfig | None = None, *, stream: str = "stream", origin: Mapping[str, Any] | None = None,
        refresh: RefreshPolicy | None = None,
    ) -> None:
        config = StreamConfig() if config is None else config
        if not isinstance(config, StreamConfig):
            raise ConfigError(f"config must be a StreamConfig; got {type(config).__name__}")
        super().__init__(config, check_stream_name(stream))
        self.origin = dict(origin) if origin is not None else None
        self._drift = DriftSettings() if self.config.drift_detection else None
        self._version = 0  # the stream's highest version handed out (one counter over all outputs)
        self._floor = 0  # versions handed out are above this (raise_version_floor)
        self._heads: dict[str, OutputHead] = {}
        self._todo: list[str] = []  # outputs of the window being identified still to do
        self._window: Window | None = None
        self._job: UpdateJob | None = None
        self._outcomes: Counter[str] = Counter()
        self._decisions: Counter[str] = Counter()
        self._drop_reasons: Counter[str] = Counter()
        self._last: dict[str, Any] = {}
        self._health = Health()  # why each output is degraded
        self._intake_fault = ""  # why the stream cannot be identified as it is sent (set by its adapter's admission)
        self._state_error = ""
        self._refresh = self.config.refresh if refresh is None else refresh
        if not isinstance(self._refresh, RefreshPolicy):
            raise ConfigError(f"refresh must be a RefreshPolicy; got {type(refresh).__name__}")
        self._tracks: dict[str, RefreshTrack] = {}

    # ---------------------------------------------------------------- identification
    @property
    def pending(self) -> int:
        """Closed windows waiting to be identified (a window with outputs still to do counts)."""
        return self._buffer.pending_windows + (1 if self._todo else 0)

    @property
    def first_run_due(self) -> bool:
        """Whether a window waits and no update of this stream has finished yet (no model, not even a refused one):
        its next job is its first run (a caller serving many streams may take it first)."""
        return (self._job is None and self.pending > 0 and not sum(self._outcomes.values())
                and all(h.model is None for h in self._heads.values()))

    @property
    def backlog(self) -> bool:
        """Whether a live stream's windows wait behind the one being identified (a backlog to catch up): a
        coevolution run due only by the schedule then waits until it is drained (:mod:`streamid.online.pending`)."""
        return self._buffer.live and self._buffer.pending_windows > 0

    @property
    def busy(self) -> bool:
        """Whether a job taken by :meth:`next_job` has not been finished yet."""
        return self._job is not None

    def next_job(self, *, defer_scheduled: bool = False, first_generations: int | None = None) -> UpdateJob | None:
        """Take the next (window, output) to identify as an :class:`UpdateJob` (None: nothing due, or a job is out).

        A window is identified once per modelled output, one job each, before the next window is taken.
        ``defer_scheduled``: the caller is loaded (other streams wait for its worker): a coevolution run due only
        by the schedule becomes a refresh, at most ``RefreshPolicy.max_every`` times in a row
        (:mod:`streamid.online.refresh`); a run forced by drift, failure or a failed re-validation never waits.
        While a live stream's windows wait behind this one (:attr:`backlog`), a run due only by the schedule
        becomes a refresh whatever the caller's load, until the backlog is drained (bounded by the backlog's own
        bound, ``max_pending_s``).
        ``first_generations``: the stream's first run (no update finished yet, no populations) runs at most this
        many generations (a caller with other streams waiting for their first runs: every stream served sooner;
        the usual warm runs go on from its populations).
        """
        if self._job is not None:
            return None
        if not self._todo:
            window = self._buffer.take()
            if window is None:
                return None
            self._window = window
            self._todo = [self.config.output] if self.config.output is not None else list(window.output_names)
        assert self._window is not None
        window, output = self._window, self._todo.pop(0)
        head = self._head(output)
        cut, generations = None, None
        if head.drift_t_ns is not None and head.drift_t_ns > window.t0_ns:
            kept = (window.t_end_ns - head.drift_t_ns) / max(1, window.t_end_ns - window.t0_ns)
            if kept >= _MIN_CUT_FRACTION:
                cut = head.drift_t_ns
        if head.escalate and (cut is not None or head.drift_t_ns is None or head.drift_t_ns <= window.t0_ns):
            generations = self.config.drift_generations
        track = self._track(output)
        why = coevolve_reason(track, head, window, self.config)
        if why and self.backlog and track.defer_for_backlog(why):  # a live backlog: caught up by refreshes first
            why = ""
        if not why or (defer_scheduled and track.defer(why)):  # a refresh of the champion's weights
            self._job = refresh_job(track, head, window, self.config, self._next_version())
            return self._job
        first = (first_generations is not None and generations is None and head.coea_state is None
                 and head.model is None and not sum(self._outcomes.values()))
        if first:
            generations = max(1, min(int(first_generations or 1), self.config.cold_generations))
        self._job = UpdateJob(
            window, self.config, self._next_version(), head.coea_state, head.signature,
            force_cold=head.failures_in_row >= self.config.cold_after_failures, output=output,
            champion=head.model, generations=generations, cut_t_ns=cut, shortened_first=first,
        )
        return self._job

    def abandon(self, job: UpdateJob) -> None:
        """Give up a job without a result (that output of its window is not identified; e.g. the caller stops)."""
        if job is self._job:
            self._job = None

    def raise_version_floor(self, version: int) -> None:
        """Hand out only versions above ``version`` (< 2**53) from now on (e.g. the highest seen on the network)."""
        if not 0 <= int(version) < MAX_VERSION:
            raise ValueError(f"a version floor must be in [0, 2**53); got {version!r}")
        self._floor = max(self._floor, int(version))

    def finish(self, job: UpdateJob, outcome: Outcome, *, now_ns: int = 0, persist: Persist | None = None) -> Update:
        """Judge a job's outcome (see :meth:`_finish`); then whether a live backlog is still kept."""
        try:
            return self._finish(job, outcome, now_ns=now_ns, persist=persist)
        finally:
            self._buffer.backlog_kept = self._can_catch_up()

    def _can_catch_up(self) -> bool:
        """Whether a live backlog can be worked through: an output has a champion to refresh, or the stream's last
        update did not fail (no update yet, or a refused challenger: its next runs are warm, from its populations).
        A stream without a model whose last update failed (an engine error, a run stopped at
        ``max_identification_s``) would decide each waiting window by another such run: it keeps only its newest
        window until it has a model."""
        return any(h.model is not None for h in self._heads.values()) or self._last.get("outcome") != "failed"

    def _finish(self, job: UpdateJob, outcome: Outcome, *, now_ns: int = 0, persist: Persist | None = None) -> Update:
        """Judge a job's outcome: the challenger becomes the champion with the next version, or is refused.

        ``now_ns`` is recorded as the document's ``published_unix_ns``.  ``persist``, when given, is
        called with the new :meth:`state` before an accepted update is returned; if it raises
        ``OSError``, ``ValueError`` or ``ModelFormatError`` the update still stands, ``Update.saved`` is
        False and :meth:`status` reports ``state_saved: false`` with the error (versions stay unique:
        they live in memory, and a daemon restart is recognised by the documents' ``origin``).

        Raises
        ------
        ValueError
            If ``job`` is not the job this identifier handed out last.
        """
        if job is not self._job:
            raise ValueError("finish() takes the job returned by this identifier's next_job(), once")
        self._job = None
        w, head = job.window, self._head(job.output or "")
        self._outcomes_count(outcome)
        self._last.update(identification_s=outcome.seconds, unix_ns=now_ns, output=head.output)
        refresh = isinstance(job, RefreshJob)
        if outcome.kind != "identified":
            if outcome.kind == "failed":
                head.failures_in_row += 1
            self._track(head.output).after(refresh=refresh, code=outcome.code or outcome.kind, accepted=False,
                                           normal=None)
            self._last["outcome"] = outcome.kind
            return self._refuse(job, outcome, outcome.kind, outcome.reason, outcome.code or outcome.kind, now_ns)
        assert outcome.model is not None and outcome.summary is not None
        if job.generations is not None and not job.shortened_first:  # escalated: until a champion is accepted, at
            # most ESCALATED_RUNS runs
            head.escalated_runs += 1
            head.escalate = head.escalated_runs < ESCALATED_RUNS
        if outcome.champion_metrics is not None and head.model is not None:
            head.current = {**outcome.champion_metrics, "t_ns": outcome.t_val_ns, "window": w.number,
                            "version": head.version}
        decision = decide(outcome, self.config, head.version)
        self._decisions[decision.code] += 1
        self._track(head.output).after(refresh=refresh, code=decision.code, accepted=decision.accepted,
                                       normal=getattr(outcome, "normal", None))
        metrics = {k: float(v) for k, v in outcome.summary.metrics.items()}
        model = outcome.model.with_metrics(**{k: v for k, v in metrics.items() if np.isfinite(v)},
                                           update="refreshed" if refresh else "identified")
        version = self._next_version() if decision.accepted else head.version
        doc = model_update_message(
            stream=self.stream, version=version, model=model.to_dict(), window=outcome.window_meta,
            metrics=metrics, warm=outcome.warm, generations=outcome.generations,
            identification_s=outcome.seconds, window_closed_unix_ns=w.received_ns, published_unix_ns=now_ns,
        )
        doc.update(output=head.output, accepted=decision.accepted, decision=decision.to_dict(),
                   update="refreshed" if refresh else "identified")
        if refresh:  # the structure kept: which champion's weights were refreshed
            doc["refreshed_from"] = int(getattr(outcome, "refreshed_from", head.version))
        if self.origin is not None:
            doc["origin"] = self.origin
        try:
            payload: bytes | None = encode_json(doc)
        except ValueError:  # NaN or infinity somewhere: never handed out
            payload = None
        if decision.code == "not_better":  # a good champion: the search goes on from this run's populations
            head.coea_state, head.signature, head.failures_in_row = outcome.state, dict(outcome.signature), 0
            head.wins += 1
        if not decision.accepted:
            self._outcomes["rejected"] += 1
            self._last["outcome"] = "rejected"
            if decision.code != "not_better":
                head.failures_in_row += 1
            return self._refuse(job, outcome, "rejected", decision.reason, decision.code, now_ns,
                                decision=decision, document=doc if payload else None, payload=payload)
        if payload is None:
            head.failures_in_row += 1
            self._outcomes["failed"] += 1
            return self._refuse(job, outcome, "failed", "model document not finite", "not_finite", now_ns)
        return self._accept(job, outcome, head, model, decision, version, doc, payload, now_ns, persist)

    def _accept(self, job: UpdateJob, outcome: Outcome, head: OutputHead, model: Model, decision: Decision,
                version: int, doc: dict[str, Any], payload: bytes, now_ns: int, persist: Persist | None) -> Update:
        w = job.window
        if head.model is not None:
            head.replaced += 1
        head.escalate = False
        self._version = version
        seen = w if job.cut_t_ns is None else cut_window(w, job.cut_t_ns)  # its reference: the data it won on
        head.new_champion(model, None if self._drift is None or head.output not in w.output_names else
                          reference_monitor(self._drift, model, seen.u, seen.y[:, w.output_names.index(head.output)],
                                            w.period_ns), window_samples=w.u.shape[0])  # (before the new version)
        head.version, head.document, head.payload = version, doc, payload
        head.coea_state, head.signature, head.failures_in_row = outcome.state, dict(outcome.signature), 0
        head.since_t_ns, head.since_unix_ns = w.t_end_ns, now_ns
        saved = True
        if persist is not None:
            try:
                persist(self.state(now_ns=now_ns))
                self._state_error = ""
            except (OSError, ValueError, ModelFormatError) as exc:
                saved = False
                if not self._state_error:
                    self._event("state.not_saved", f"state could not be saved ({exc}); models are still published, "
                                "versions kept unique in memory", w.t_end_ns, now_ns)
                self._state_error = str(exc)[:300] or type(exc).__name__
        self._outcomes["accepted"] += 1
        self._health.set(head.output, "", self._buffer.output_names)  # (another output's health is its own)
        m = outcome.summary.metrics if outcome.summary is not None else {}
        self._last.update(outcome="accepted", r2_osa_val=m.get("r2_osa_val"), r2_fr_val=m.get("r2_fr_val"),
                          model_unix_ns=now_ns)
        ev = self._event(
            "update.accepted",
            f"window {w.number}: {head.output} model v{version} accepted "
            f"({'refreshed' if isinstance(job, RefreshJob) else 'warm' if outcome.warm else 'cold'}, "
            f"R² validation OSA {m.get('r2_osa_val', float('nan')):.4f} FR {m.get('r2_fr_val', float('nan')):.4f}; "
            f"{decision.code})",
            w.t_end_ns, now_ns,
        )
        return Update("accepted", decision.reason, decision.code, version, w, outcome, doc, payload, ev, head.output,
                      decision, saved)

    def update(
        self,
        *,
        helper: EvalHelper | None = None,
        stop: StopFlag | None = None,
        on_generation: Callable[[str, Any], None] | None = None,
        now_ns: int = 0,
        persist: Persist | None = None,
    ) -> Update | None:
        """Identify the oldest pending window (its next output) now, on this thread (None: nothing is due)."""
        job = self.next_job()
        if job is None:
            return None
        try:
            outcome = job.run(stop=stop, on_generation=on_generation, helper=helper)
        except BaseException:
            self.abandon(job)
            raise
        return self.finish(job, outcome, now_ns=now_ns, persist=persist)

    def update_all(self, **kwargs: Any) -> list[Update]:
        """:meth:`update` until no window is pending; the updates, oldest window first."""
        out: list[Update] = []
        while (up := self.update(**kwargs)) is not None:
            out.append(up)
        return out

    # ---------------------------------------------------------------- state
    def state(self, *, now_ns: int = 0) -> StreamState:
        """What :meth:`from_state` resumes from: version, and per output the champion, populations, failures.

        The window's samples are not part of it: a resumed identifier starts with an empty
        window and its first run warm-starts from the populations.
        """
        heads = list(self._heads.values())
        first = heads[0].snapshot() if heads else {}
        return StreamState(
            stream=self.stream,
            version=max(self._version, self._floor),
            signature=first.get("signature", {}),
            model_message=first.get("model_message"),
            coea_state=first.get("coea_state"),
            saved_unix_ns=now_ns,
            failures_in_row=first.get("failures_in_row", 0),
            others={h.output: h.snapshot() for h in heads[1:]},
            refresh={h.output: self._track(h.output).snapshot() for h in heads},
        )

    @classmethod
    def from_state(cls, state: StreamState, config: StreamConfig | None = None,
                   origin: Mapping[str, Any] | None = None, refresh: RefreshPolicy | None = None) -> OnlineIdentifier:
        """A new identifier that resumes from :meth:`state` (see :meth:`restore`)."""
        ident = cls(config, stream=state.stream, origin=origin, refresh=refresh)
        ident.restore(state)
        return ident

    def restore(self, state: StreamState) -> list[str]:
        """Resume from a saved state; returns warnings about the parts that could not be used.

        The version always carries over (numbers never repeat).  An unreadable model document
        leaves that output without a champion; unusable populations make its next run start cold.

        Raises
        ------
        ValueError
            If ``state`` belongs to another stream.
        """
        if state.stream != self.stream:
            raise ValueError(f"state of stream {state.stream!r} cannot resume stream {self.stream!r}")
        warnings: list[str] = []
        self._version = int(state.version)
        self._heads.clear()
        parts: list[tuple[dict[str, Any], str | None]] = [({"version": state.version, "signature": state.signature, "model_message": state.model_message,
                   "coea_state": state.coea_state, "failures_in_row": state.failures_in_row}, None)]
        parts += [(v, k) for k, v in state.others.items()]
        for part, name in parts:
            head = restored_head(part, name, warnings)
            if head is not None:
                self._heads[head.output] = head
        self._buffer.backlog_kept = True  # (a restored champion: a backlog can be refreshed through)
        self._tracks.clear()
        for output, part in state.refresh.items():
            if output in self._heads and (why := self._track(output).restore(part)):
                warnings.append(why)
                self._tracks.pop(output)
        return warnings

    # ---------------------------------------------------------------- status and events
    @property
    def degraded(self) -> bool:
        """Whether an output's last update was not accepted for a fault or an invalid challenger, or the stream cannot
        be identified as it is sent (reason in :meth:`status`).  Each output of a stream of several is healthy or not
        on its own: a model accepted for one does not make another's failure go away."""
        return bool(self._intake_fault) or bool(self._health.current(self._buffer.output_names))

    def intake_fault(self, reason: str) -> None:
        """The stream cannot be identified as it is sent (e.g. its window needs more memory than the daemon allows
        one identification, or it has more channels than allowed): degraded for ``reason`` until its batches are
        taken again (``reason`` empty). A stream never identified for such a reason is never ``ok``."""
        self._intake_fault = str(reason)

    def status(self, *, now_ns: int = 0) -> dict[str, Any]:
        """The ``streamid.status/1`` document of this stream (the daemon adds its own part)."""
        return stream_status(
            self.stream, self._buffer.counters(), list(self._heads.values()), now_ns=now_ns,
            degraded_reason=self._intake_fault or self._health.text(
                self._buffer.output_names,
                one_output=self.config.output is not None or max(len(self._buffer.output_names), len(self._heads)) <= 1),
            version=self._version, busy=self.busy,
            outcomes=self._outcomes, decisions=self._decisions, drop_reasons=self._drop_reasons,
            last=self._last, events_dropped=self._events_dropped, state_error=self._state_error,
            outputs_to_do=len(self._todo),
            refresh={h.output: self._track(h.output).summary(coevolve_reason(self._track(h.output), h, None, self.config))
                     for h in self._heads.values()},
            refresh_policy=self._refresh.to_dict(),
        )

    # ---------------------------------------------------------------- internals
    def _next_version(self) -> int:
        return max(self._version, self._floor) + 1

    def _track(self, output: str) -> RefreshTrack:
        track = self._tracks.get(output)
        if track is None:
            track = self._tracks[output] = RefreshTrack(self._refresh)
        return track

    def next_is_refresh(self, *, defer_scheduled: bool = False) -> bool:
        """Whether the next update of the window to come (its first output) would refresh the champion's weights
        (``defer_scheduled`` as for :meth:`next_job`)."""
        head = self._heads.get(self._todo[0]) if self._todo else self._primary()
        if head is None:
            return False
        track = self._track(head.output)
        why = coevolve_reason(track, head, None, self.config)
        return not why or ((defer_scheduled or self.backlog) and track.deferrable(why, backlog=self.backlog))

    def _head(self, output: str) -> OutputHead:
        head = self._heads.get(output)
        if head is None:
            head = self._heads[output] = OutputHead(output)
        return head

    def _watch(self, now_ns: int) -> None:
        """Run each champion free over the blocks of samples just completed (:mod:`streamid.online.watch`)."""
        for d in watch_blocks(self._heads.values(), self._buffer):
            mon = d.monitor
            level = mon.last_level if mon is not None else float("nan")
            ratio = "diverged" if not np.isfinite(level) else f"{np.exp(level):.2f} x"
            whose = f"champion v{d.version}" if d.version == d.head.version else f"v{d.version} (replaced, still watched)"
            self._event("drift", f"{d.head.output}: the output's level moved away from {whose}'s "
                        f"free run (last block: measured/model amplitude {ratio} its reference); change estimated "
                        f"at stream time {d.change_ns / 1e9:.2f} s: the next identification uses data from then on "
                        f"with {self.config.drift_generations} generations", d.t_end_ns, now_ns)

    def _outcomes_count(self, outcome: Outcome) -> None:
        if outcome.kind == "dropped":
            self._outcomes["dropped"] += 1
            self._drop_reasons[outcome.code or "other"] += 1
        elif outcome.kind == "failed":
            self._outcomes["failed"] += 1

    def _refuse(self, job: UpdateJob, outcome: Outcome, kind: str, reason: str, code: str, now_ns: int, *,
                decision: Decision | None = None, document: dict[str, Any] | None = None,
                payload: bytes | None = None) -> Update:
        health = degraded_after(decision, self.config) if decision is not None else None
        w, output = job.window, job.output or ""
        if health is not None:  # the champion ran on the same data: the output's health is its validity there
            self._health.set(output, health, self._buffer.output_names)
        elif code != "not_better":
            self._health.set(output, reason or kind, self._buffer.output_names)
        ev = self._event(f"update.{kind}", f"window {w.number} {output} {kind}: {reason}", w.t_end_ns, now_ns)
        version = self._heads[output].version if output in self._heads else 0
        return Update(kind, reason, code, version, w, outcome, document, payload, ev, output, decision)
