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

**Acceptance.**  A candidate is accepted when its predictions and figures on the held-out
newest part of the window are finite, its one-step-ahead R^2 there reaches
``min_r2_osa`` and its free-run R^2 reaches ``min_r2_fr``; it then becomes the current model
with the next version.  Otherwise the update is *rejected* (the model is not finite or
not good enough), *failed* (the engine raised) or *dropped* (the window cannot be
identified: too short, constant signal, missing output), the current model stays and the
stream is marked degraded with the reason.  After ``cold_after_failures`` failed updates in a
row the next run starts cold; a run whose signals, period or search size differ from the
populations' starts cold too.

Everything that happens comes back as a value: :meth:`push` returns the
:class:`~streamid.online.window_types.Event` s it raised (gap, reset, refused batch, window
closed or coalesced), :meth:`finish` an :class:`Update` that carries its own event; the
newest 256 events are also kept for :meth:`drain_events`.  Times the caller wants recorded
(when a batch arrived, when a model was published) are passed in as ``now_ns``.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.engine import CoEAState, EvalHelper, Model
from streamid.errors import ConfigError, DataError, ModelFormatError, StreamidError
from streamid.online.acceptance import Update, judge
from streamid.online.arrays_in import batch_of, columns, signal_names
from streamid.online.snapshot import StreamState
from streamid.online.stream_config import StreamConfig
from streamid.online.update import Outcome, StopFlag, UpdateJob
from streamid.online.window import WindowBuffer
from streamid.online.window_types import BatchLike, Event
from streamid.wire.documents import STATUS_FORMAT, encode_json, model_update_message
from streamid.wire.keys import check_stream_name

__all__ = ["OnlineIdentifier", "Update", "Persist"]

#: Events kept for :meth:`OnlineIdentifier.drain_events` (the newest; older ones are dropped, counted).
EVENTS_KEPT = 256

#: Called by :meth:`OnlineIdentifier.finish` with the state after an accepted update, before it
#: is returned: an exception (``OSError``, ``ValueError``, ``ModelFormatError``) undoes the update.
Persist = Callable[[StreamState], object]

_UPDATE_KINDS = ("accepted", "rejected", "failed", "dropped")
#: Samples of the first batch :meth:`OnlineIdentifier.learn_many` makes of a long record (the period is not known yet).
_FIRST_CHUNK = 256


class OnlineIdentifier:
    """Online identification of one stream (single-threaded; see the module docstring).

    Parameters
    ----------
    config
        The stream's settings (default: :class:`StreamConfig` defaults: 10 s windows,
        an update every second).
    stream
        The stream's name (``[A-Za-z0-9_.-]{1,128}``), used in windows, events and documents.

    Examples
    --------
    >>> from streamid import OnlineIdentifier, StreamConfig
    >>> from streamid.sim import get_device
    >>> t_ns, u, y = get_device("mr_damper").simulate_seconds(12.0, seed=1)
    >>> cfg = StreamConfig(window_s=4.0, update_every_s=4.0, cold_generations=60, max_pending_windows=8)
    >>> ident = OnlineIdentifier(cfg, stream="damper")
    >>> events = ident.learn_many(t_ns, u, y, inputs=["velocity_cm_s"], outputs=["force_N"])
    >>> [(up.kind, up.version) for up in ident.update_all()]  # doctest: +SKIP
    [('accepted', 1), ('accepted', 2), ('accepted', 3)]
    """

    def __init__(self, config: StreamConfig | None = None, *, stream: str = "stream") -> None:
        self.config = StreamConfig() if config is None else config
        if not isinstance(self.config, StreamConfig):
            raise ConfigError(f"config must be a StreamConfig; got {type(self.config).__name__}")
        self.stream = check_stream_name(stream)
        self._buffer = WindowBuffer(self.stream, self.config.window_params())
        self._version = 0
        self._model: Model | None = None
        self._document: dict[str, Any] | None = None
        self._payload: bytes | None = None
        self._coea_state: CoEAState | None = None
        self._signature: dict[str, Any] | None = None
        self._failures_in_row = 0
        self._job: UpdateJob | None = None
        self._outcomes: Counter[str] = Counter()
        self._drop_reasons: Counter[str] = Counter()
        self._last: dict[str, Any] = {}
        self._degraded_reason = ""
        self._events: deque[Event] = deque(maxlen=EVENTS_KEPT)
        self._events_dropped = 0
        self._seq = 0
        self._staged: tuple[int, NDArray[np.float64], NDArray[np.float64]] | None = None

    # ---------------------------------------------------------------- samples in
    def push(self, batch: BatchLike, *, source: str = "samples", now_ns: int = 0) -> list[Event]:
        """Add one batch of samples; returns the events it raised.

        ``source`` is the key the batch came on (``samples``, or ``u`` / ``y`` for inputs
        and outputs published apart, aligned by time).  ``now_ns`` is the caller's clock
        reading (kept with the windows this batch closes).  Never raises for bad data: a
        refused batch is a ``bad.<why>`` event and a count in :meth:`status`.
        """
        self._buffer.append(batch, source, now_ns=now_ns)
        return self._collect()

    def learn_many(
        self,
        t_ns: ArrayLike,
        u: ArrayLike,
        y: ArrayLike,
        *,
        inputs: Sequence[str] | None = None,
        outputs: Sequence[str] | None = None,
        period_ns: int | None = None,
        now_ns: int = 0,
    ) -> list[Event]:
        """Add samples given as arrays; returns the events they raised.

        Parameters
        ----------
        t_ns : array_like of int, shape (N,)
            Sample times in integer nanoseconds, strictly increasing.
        u : array_like, shape (N,) or (N, n_inputs)
        y : array_like, shape (N,) or (N, n_outputs)
        inputs, outputs
            Signal names (default ``u``/``u0, u1...`` and ``y``/``y0, y1...``).
        period_ns
            The sample period, when ``t_ns`` alone cannot tell it (a single first sample).

        Raises
        ------
        DataError
            If the arrays do not have the shapes above, or names do not match the columns.
        """
        t = np.atleast_1d(np.asarray(t_ns))
        if t.ndim != 1 or t.dtype.kind not in "iu":
            raise DataError(f"t_ns must be a 1-D array of integer nanoseconds; got dtype {t.dtype} shape {t.shape}")
        ua = columns(u, t.size, "u")
        ya = columns(y, t.size, "y")
        in_names = signal_names(inputs, ua.shape[1], "u")
        out_names = signal_names(outputs, ya.shape[1], "y")
        if t.size == 0:
            return []
        if self._buffer.period_ns is None and period_ns is None and t.size == 1:
            if self._staged is None:  # one sample cannot tell the period: wait for the next
                self._staged = (int(t[0]), ua, ya)
                return []
            t0, u0, y0 = self._staged
            t, ua, ya = np.r_[t0, t], np.vstack([u0, ua]), np.vstack([y0, ya])
        self._staged = None
        t = t.astype(np.int64)
        events: list[Event] = []
        a = 0
        while a < t.size:
            # at most one hop per batch: a long record closes every window it spans (the ring holds
            # one window and a hop; a larger batch would overwrite windows before they close)
            b = a + max(2, self._buffer.lengths[1] or _FIRST_CHUNK)
            if t.size - b == 1:
                b += 1  # never leave one sample alone: it cannot tell the period of a new stream
            batch = batch_of(self.stream, self._seq, t[a:b], ua[a:b], ya[a:b], in_names, out_names,
                             period_ns or self._buffer.period_ns or 0)
            self._seq += 1
            events += self.push(batch, now_ns=now_ns)
            a = b
        return events

    def learn_one(
        self, t_ns: int, u: float | ArrayLike, y: float | ArrayLike, *, period_ns: int | None = None, now_ns: int = 0
    ) -> list[Event]:
        """Add one sample (``u``, ``y``: a number or one value per signal); returns the events it raised."""
        return self.learn_many(
            np.array([t_ns], dtype=np.int64), np.atleast_2d(np.asarray(u, dtype=np.float64).ravel()),
            np.atleast_2d(np.asarray(y, dtype=np.float64).ravel()), period_ns=period_ns, now_ns=now_ns,
        )

    def count_bad(self, kind: str, message: str = "", *, now_ns: int = 0) -> list[Event]:
        """Count a bad message the caller found before the samples (e.g. undecodable bytes)."""
        self._buffer.count_bad(kind, message, now_ns=now_ns)
        return self._collect()

    # ---------------------------------------------------------------- identification
    @property
    def pending(self) -> int:
        """Closed windows waiting to be identified."""
        return self._buffer.pending_windows

    @property
    def busy(self) -> bool:
        """Whether a job taken by :meth:`next_job` has not been finished yet."""
        return self._job is not None

    def next_job(self) -> UpdateJob | None:
        """Take the oldest pending window as an :class:`UpdateJob` (None: nothing due, or a job is out)."""
        if self._job is not None:
            return None
        window = self._buffer.take()
        if window is None:
            return None
        self._job = UpdateJob(
            window, self.config, self._version + 1, self._coea_state, self._signature,
            force_cold=self._failures_in_row >= self.config.cold_after_failures,
        )
        return self._job

    def abandon(self, job: UpdateJob) -> None:
        """Give up a job without a result (its window is not identified; e.g. the caller stops)."""
        if job is self._job:
            self._job = None

    def finish(self, job: UpdateJob, outcome: Outcome, *, now_ns: int = 0, persist: Persist | None = None) -> Update:
        """Judge a job's outcome: accept it as the next version, or refuse it with the reason.

        ``now_ns`` is recorded as the document's ``published_unix_ns``.  ``persist``, when
        given, is called with the new :meth:`state` before an accepted update is returned; if
        it raises ``OSError``, ``ValueError`` or ``ModelFormatError`` the update is undone and
        returned as failed (``state_not_saved``): a version is never handed out twice.

        Raises
        ------
        ValueError
            If ``job`` is not the job this identifier handed out last.
        """
        if job is not self._job:
            raise ValueError("finish() takes the job returned by this identifier's next_job(), once")
        self._job = None
        w = job.window
        self._outcomes_count(outcome)
        self._last.update(identification_s=outcome.seconds, unix_ns=now_ns)
        if outcome.kind != "identified":
            if outcome.kind == "failed":
                self._failures_in_row += 1
            self._last["outcome"] = outcome.kind
            return self._refuse(job, outcome, outcome.kind, outcome.reason, outcome.code or outcome.kind, now_ns)
        reasons = judge(outcome, self.config)
        if reasons:
            self._failures_in_row += 1
            self._outcomes["rejected"] += 1
            self._last["outcome"] = "rejected"
            return self._refuse(job, outcome, "rejected", "; ".join(reasons), "validation", now_ns)
        assert outcome.model is not None and outcome.summary is not None
        metrics = {k: float(v) for k, v in outcome.summary.metrics.items()}
        model = outcome.model.with_metrics(**{k: v for k, v in metrics.items() if np.isfinite(v)})
        doc = model_update_message(
            stream=self.stream, version=job.version, model=model.to_dict(), window=outcome.window_meta,
            metrics=metrics, warm=outcome.warm, generations=outcome.generations,
            identification_s=outcome.seconds, window_closed_unix_ns=w.received_ns, published_unix_ns=now_ns,
        )
        try:
            payload = encode_json(doc)
        except ValueError as exc:  # NaN or infinity somewhere: never handed out
            self._failures_in_row += 1
            self._outcomes["failed"] += 1
            return self._refuse(job, outcome, "failed", f"model document not finite ({exc})", "not_finite", now_ns)
        prev = (self._version, self._model, self._document, self._payload, self._coea_state, self._signature)
        self._version, self._model, self._document, self._payload = job.version, model, doc, payload
        self._coea_state, self._signature = outcome.state, dict(outcome.signature)
        if persist is not None:
            try:
                persist(self.state(now_ns=now_ns))
            except (OSError, ValueError, ModelFormatError) as exc:
                (self._version, self._model, self._document, self._payload, self._coea_state, self._signature) = prev
                self._outcomes["failed"] += 1
                return self._refuse(job, outcome, "failed", f"state could not be saved ({exc}); model not published",
                                    "state_not_saved", now_ns)
        self._outcomes["accepted"] += 1
        self._failures_in_row = 0
        self._degraded_reason = ""
        self._last.update(outcome="accepted", r2_osa_val=metrics.get("r2_osa_val"),
                          r2_fr_val=metrics.get("r2_fr_val"), model_unix_ns=now_ns)
        ev = self._event(
            "update.accepted",
            f"window {w.number}: model v{job.version} accepted ({'warm' if outcome.warm else 'cold'}, "
            f"R² validation OSA {metrics.get('r2_osa_val', float('nan')):.4f} FR {metrics.get('r2_fr_val', float('nan')):.4f})",
            w.t_end_ns, now_ns,
        )
        return Update("accepted", "", "", job.version, w, outcome, doc, payload, ev)

    def update(
        self,
        *,
        helper: EvalHelper | None = None,
        stop: StopFlag | None = None,
        on_generation: Callable[[str, Any], None] | None = None,
        now_ns: int = 0,
        persist: Persist | None = None,
    ) -> Update | None:
        """Identify the oldest pending window now, on this thread (None: nothing is due)."""
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

    # ---------------------------------------------------------------- the current model
    @property
    def version(self) -> int:
        """Version of the current model (0: none yet)."""
        return self._version

    @property
    def model(self) -> Model | None:
        """The current model (the last accepted), with its validation figures in ``metrics``."""
        return self._model

    @property
    def document(self) -> dict[str, Any] | None:
        """The current model's update document (``streamid.model-update/1``), or None."""
        return self._document

    @property
    def payload(self) -> bytes | None:
        """:attr:`document` as compact JSON bytes (what the daemon publishes), or None."""
        return self._payload

    def predict_one(self) -> float | None:
        """One-step-ahead prediction of the next output sample from the newest samples held.

        None if there is no model yet or fewer than ``max_lag`` complete samples are held
        since the last gap or reset.  The model's lags start at 1, so no input at the
        predicted instant is needed.
        """
        m = self._model
        if m is None:
            return None
        recent = self._buffer.recent(m.max_lag)
        if recent is None:
            return None
        u, y = recent
        col = self._output_column(y.shape[1])
        if col is None or u.shape[1] != m.n_inputs:
            return None
        u1 = np.vstack([u, u[-1:]])  # the row of the predicted instant: its values are never used (lags >= 1)
        y1 = np.r_[y[:, col], y[-1, col]]
        return float(m.predict_osa(u1, y1)[-1])

    def simulate(self, u: ArrayLike, y_init: ArrayLike) -> NDArray[np.float64]:
        """Free run of the current model on inputs ``u`` from ``max_lag`` measured outputs ``y_init``.

        Raises
        ------
        DataError
            If there is no model yet, or the data do not fit it.
        """
        if self._model is None:
            raise DataError("no model yet: simulate() needs an accepted update first (see update())")
        return self._model.simulate(u, y_init)

    # ---------------------------------------------------------------- state
    def state(self, *, now_ns: int = 0) -> StreamState:
        """What :meth:`from_state` resumes from: version, model document, populations, failures.

        The window's samples are not part of it: a resumed identifier starts with an empty
        window and its first run warm-starts from the populations.
        """
        return StreamState(
            stream=self.stream,
            version=self._version,
            signature=dict(self._signature or {}),
            model_message=self._document,
            coea_state=self._coea_state.to_json() if self._coea_state is not None else None,
            saved_unix_ns=now_ns,
            failures_in_row=self._failures_in_row,
        )

    @classmethod
    def from_state(cls, state: StreamState, config: StreamConfig | None = None) -> OnlineIdentifier:
        """A new identifier that resumes from :meth:`state` (see :meth:`restore`)."""
        ident = cls(config, stream=state.stream)
        ident.restore(state)
        return ident

    def restore(self, state: StreamState) -> list[str]:
        """Resume from a saved state; returns warnings about the parts that could not be used.

        The version always carries over (numbers never repeat).  An unreadable model document
        leaves no current model; unusable populations make the next run start cold.

        Raises
        ------
        ValueError
            If ``state`` belongs to another stream.
        """
        if state.stream != self.stream:
            raise ValueError(f"state of stream {state.stream!r} cannot resume stream {self.stream!r}")
        warnings: list[str] = []
        self._version = int(state.version)
        self._failures_in_row = int(state.failures_in_row)
        self._model = self._document = self._payload = None
        if state.model_message is not None:
            try:
                self._payload = encode_json(state.model_message)
                self._model = Model.from_dict(state.model_message.get("model"))
                self._document = dict(state.model_message)
            except (ValueError, StreamidError) as exc:
                self._model = self._document = self._payload = None
                warnings.append(f"saved model unusable ({exc}); no current model until the next update")
        self._coea_state, self._signature = None, None
        if state.coea_state is not None:
            try:
                self._coea_state = CoEAState.from_json(state.coea_state)
                self._signature = dict(state.signature)
            except (StreamidError, ValueError) as exc:
                warnings.append(f"saved populations unusable ({exc}); the next run starts cold")
        return warnings

    # ---------------------------------------------------------------- status and events
    @property
    def degraded(self) -> bool:
        """Whether the last update was not accepted (the reason is in :meth:`status`)."""
        return bool(self._degraded_reason)

    def counters(self) -> dict[str, object]:
        """The window buffer's counters (samples, batches, bad input, gaps, resets, windows...)."""
        return self._buffer.counters()

    def status(self, *, now_ns: int = 0) -> dict[str, Any]:
        """The ``streamid.status/1`` document of this stream (the daemon adds its own part)."""
        c = self._buffer.counters()
        return {
            "format": STATUS_FORMAT,
            "stream": self.stream,
            "unix_ns": now_ns,
            "degraded": self.degraded,
            "degraded_reason": self._degraded_reason,
            "version": self._version,
            "busy": self.busy,
            "samples_in": c.get("samples_in", 0),
            "batches_in": c.get("batches_in", 0),
            "bad": c["bad"],
            "bad_total": c["bad_total"],
            "last_bad": c.get("last_bad") or None,
            "windows": {
                "closed": c.get("windows_closed", 0),
                "emitted": c.get("windows_emitted", 0),
                "coalesced": c.get("windows_coalesced", 0),
                "dropped": int(self._outcomes.get("dropped", 0)),
                **{k: c[k] for k in ("pending", "pending_windows", "max_pending_windows", "pending_bytes",
                                     "pending_windows_peak", "pending_bytes_peak", "pending_bytes_max")},
            },
            "identifications": {k: int(self._outcomes.get(k, 0)) for k in _UPDATE_KINDS},
            "drop_reasons": dict(self._drop_reasons),
            "failures_in_row": self._failures_in_row,
            "last": {k: v for k, v in self._last.items() if v is not None},
            "gaps": c.get("gaps", 0),
            "gap_samples": c.get("gap_samples", 0),
            "resets": c["resets"],
            "unaligned": c.get("unaligned", 0),
            "samples_discarded": c.get("samples_discarded", 0),
            "events_dropped": self._events_dropped,
            **{k: c[k] for k in ("period_ns", "window_samples", "hop_samples", "inputs", "outputs")},
        }

    def drain_events(self) -> list[Event]:
        """Remove and return the events kept since the last call (the newest :data:`EVENTS_KEPT`)."""
        self._collect()
        out = list(self._events)
        self._events.clear()
        return out

    # ---------------------------------------------------------------- internals
    def _collect(self) -> list[Event]:
        new = self._buffer.drain_events()
        for ev in new:
            self._keep(ev)
        return new

    def _keep(self, ev: Event) -> None:
        if len(self._events) == self._events.maxlen:
            self._events_dropped += 1
        self._events.append(ev)

    def _event(self, kind: str, message: str, t_ns: int | None, now_ns: int) -> Event:
        ev = Event(kind, f"{self.stream}: {message}", t_ns, now_ns)
        self._keep(ev)
        return ev

    def _outcomes_count(self, outcome: Outcome) -> None:
        if outcome.kind == "dropped":
            self._outcomes["dropped"] += 1
            self._drop_reasons[outcome.code or "other"] += 1
        elif outcome.kind == "failed":
            self._outcomes["failed"] += 1

    def _refuse(self, job: UpdateJob, outcome: Outcome, kind: str, reason: str, code: str, now_ns: int) -> Update:
        self._degraded_reason = reason[:500] or kind
        w = job.window
        ev = self._event(f"update.{kind}", f"window {w.number} {kind}: {reason}", w.t_end_ns, now_ns)
        return Update(kind, reason, code, self._version, w, outcome, None, None, ev)

    def _output_column(self, n_outputs: int) -> int | None:
        names = self._buffer.output_names
        want = self.config.output
        if want is None:
            return 0 if n_outputs else None
        return names.index(want) if want in names else None

