"""The ``streamid.status/1`` document of one stream, built from an identifier's parts (pure, no I/O)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

from streamid.online.head import OutputHead
from streamid.wire.documents import STATUS_FORMAT

__all__ = ["stream_status", "UPDATE_KINDS"]

UPDATE_KINDS = ("accepted", "rejected", "failed", "dropped")


def _champion(head: OutputHead, now_ns: int, last_t_ns: int | None) -> dict[str, Any]:
    cur = {k: v for k, v in head.current.items() if v is None or isinstance(v, (int, str)) or v == v}
    return {
        "version": head.version,
        "age_s": (last_t_ns - head.since_t_ns) / 1e9 if head.since_t_ns is not None and last_t_ns else None,
        "age_wall_s": (now_ns - head.since_unix_ns) / 1e9 if head.since_unix_ns and now_ns else None,
        "wins": head.wins,
        "current": cur or None,  # its re-validation on the newest held-out data (r2_fr_val, r2_osa_val, t_ns)
        "at_acceptance": {k: head.model.metrics.get(k) for k in ("r2_fr_val", "r2_osa_val")} if head.model else None,
    }


def stream_status(
    stream: str,
    c: Mapping[str, Any],
    heads: Sequence[OutputHead],
    *,
    now_ns: int,
    degraded_reason: str,
    version: int,
    busy: bool,
    outcomes: Counter[str],
    decisions: Counter[str],
    drop_reasons: Counter[str],
    last: Mapping[str, Any],
    events_dropped: int,
    state_error: str,
    outputs_to_do: int = 0,
    refresh: Mapping[str, Mapping[str, Any]] | None = None,
    refresh_policy: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The status document (``c``: the window buffer's counters; ``refresh``: per output, its
    :meth:`~streamid.online.refresh.RefreshTrack.summary`, with ``refresh_policy`` the policy's settings)."""
    refresh = refresh or {}
    first_refresh = dict(refresh[heads[0].output]) if heads and heads[0].output in refresh else None
    last_t_ns = c.get("last_t_ns")
    outputs = {
        h.output: {
            "version": h.version,
            "champion": _champion(h, now_ns, last_t_ns) if h.model is not None else None,
            "losses": h.replaced,
            "failures_in_row": h.failures_in_row,
            "drifts": h.drifts,
            "drift_t_ns": h.drift_t_ns,
            "escalated": h.escalate,
            "drift_watch": h.monitor.summary() if h.monitor is not None else None,
            "drift_watch_replaced": [{"version": w.version, "blocks_left": w.blocks_left, **w.monitor.summary()}
                                     for w in h.retired],
            "refresh": dict(refresh[h.output]) if h.output in refresh else None,
        }
        for h in heads
    }
    first = heads[0] if heads else None
    return {
        "format": STATUS_FORMAT,
        "stream": stream,
        "unix_ns": now_ns,
        "degraded": bool(degraded_reason),
        "degraded_reason": degraded_reason,
        "version": version,
        "busy": busy,
        "samples_in": c.get("samples_in", 0),
        "batches_in": c.get("batches_in", 0),
        "bad": c["bad"],
        "bad_total": c["bad_total"],
        "last_bad": c.get("last_bad") or None,
        "windows": {
            "closed": c.get("windows_closed", 0),
            "emitted": c.get("windows_emitted", 0),
            "coalesced": c.get("windows_coalesced", 0),
            "dropped": int(outcomes.get("dropped", 0)),
            "pending": bool(c["pending"] or outputs_to_do),
            "outputs_to_do": outputs_to_do,  # outputs of the window being identified not done yet
            **{k: c[k] for k in ("pending_windows", "max_pending_windows", "pending_bytes",
                                 "pending_windows_peak", "pending_bytes_peak", "pending_bytes_max", "live",
                                 "max_pending_s", "backlog_kept")},
            # the backlog: stream time from the oldest waiting window's end to the newest's, and how long the
            # oldest has waited (the caller's clock; None without one)
            "backlog_s": round(float(c["pending_span_s"]), 6),
            "backlog_age_s": _age_s(now_ns, c.get("pending_oldest_received_ns")),
        },
        "identifications": {k: int(outcomes.get(k, 0)) for k in UPDATE_KINDS},
        "decisions": dict(decisions),
        "champion": outputs[first.output]["champion"] if first is not None else None,
        "models": outputs,  # per modelled output: its champion, losses, failures, drifts
        # the first output's refresh policy state: next update a refresh or a coevolution run, and why
        "refresh": {**first_refresh, "policy": dict(refresh_policy or {})} if first_refresh is not None else None,
        "drifts": sum(h.drifts for h in heads),
        "drop_reasons": dict(drop_reasons),
        "failures_in_row": first.failures_in_row if first is not None else 0,
        "state_saved": not state_error,
        "state_error": state_error,
        "last": {k: v for k, v in last.items() if v is not None},
        "gaps": c.get("gaps", 0),
        "gap_samples": c.get("gap_samples", 0),
        "resets": c["resets"],
        "unaligned": c.get("unaligned", 0),
        "samples_discarded": c.get("samples_discarded", 0),
        "events_dropped": events_dropped,
        **{k: c[k] for k in ("period_ns", "window_samples", "hop_samples", "inputs", "outputs")},
    }


def _age_s(now_ns: int, since_ns: object) -> float | None:
    """Seconds from ``since_ns`` to ``now_ns`` (None: either unknown, i.e. 0 or None)."""
    if not isinstance(since_ns, int) or since_ns <= 0 or now_ns <= 0:
        return None
    return round(max(0, now_ns - since_ns) / 1e9, 3)
