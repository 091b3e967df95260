"""The drift watch over incoming samples: each champion run free over the blocks just completed.

:func:`watch_blocks` is the body of :meth:`OnlineIdentifier._watch
<streamid.online.OnlineIdentifier>`, called after every batch: for each output
whose champion has a :class:`~streamid.online.drift.DriftMonitor` (and for each
replaced champion still watched, :attr:`OutputHead.retired
<streamid.online.head.OutputHead>`), the complete blocks of samples since its
last block are run through that model (:func:`~streamid.online.drift.block_levels`)
and fed to its monitor.  On a signal it marks the head (``drift_t_ns``,
``escalate``, ``drifts``), ends the replaced champions' watch and spends the
champion's monitor (one change, one event), and returns the drift; the
identifier turns it into a ``drift`` event.  No clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from streamid.model import Model
from streamid.online.drift import DriftMonitor, block_levels
from streamid.online.head import OutputHead
from streamid.online.window import WindowBuffer

__all__ = ["Drift", "watch_blocks"]


@dataclass(frozen=True)
class Drift:
    """One signal of a monitor: its output's head, the estimated start of the change and the signalling block's end."""

    head: OutputHead
    change_ns: int
    t_end_ns: int
    monitor: DriftMonitor
    version: int  # of the model whose monitor signalled (the champion's, or a replaced champion's)


def watch_blocks(heads: Iterable[OutputHead], buffer: WindowBuffer) -> list[Drift]:
    """Feed every watched champion the blocks completed since its last one; the drifts they signalled."""
    heads = list(heads)
    epoch, complete = buffer.position
    names, cap = buffer.output_names, buffer.lengths[2]
    due: list[tuple[OutputHead, DriftMonitor, Model, int, int, int]] = []  # (..., version, first sample, samples it needs)
    watched: list[tuple[OutputHead, DriftMonitor | None, Model | None, int]] = [
        (head, w.monitor, w.model, w.version) for head in heads for w in head.retired]
    watched += [(head, head.monitor, head.model, head.version) for head in heads]
    for head, mon, m, version in watched:
        if mon is None or m is None or head.output not in names:
            continue
        if mon.epoch != epoch or mon.next_index is None or complete - mon.next_index + m.max_lag > cap:
            mon.epoch, mon.next_index = epoch, complete  # (re)start at the newest sample
        elif complete - mon.next_index >= mon.block_samples:
            due.append((head, mon, m, version, mon.next_index, complete - mon.next_index + m.max_lag))
    got = buffer.recent(max(n for *_, n in due)) if due else None  # one copy for every output
    if got is None:
        return []
    found: list[Drift] = []
    for head, mon, m, version, first, need in due:
        if mon is not head.monitor and not any(w.monitor is mon for w in head.retired):
            continue  # a replaced champion's watch ended by a signal earlier in this call
        u, y = got[0][-need:], got[1][-need:, names.index(head.output)]
        if u.shape[1] != m.n_inputs:
            continue
        B = mon.block_samples
        n_blocks = (complete - first) // B
        lv = block_levels(m, u[: m.max_lag + n_blocks * B], y[: m.max_lag + n_blocks * B], B)
        period = int(buffer.period_ns or 0)
        ends = buffer.times_ns(first + B - 1, 1)[0] + np.arange(n_blocks, dtype=np.int64) * B * period
        mon.next_index = first + n_blocks * B
        for level, r, mr, t_end in zip(lv.level, lv.rms, lv.model_rms, ends, strict=True):
            change_ns = mon.block(float(level), float(r), float(mr), int(t_end))
            if change_ns is not None:
                head.drift_t_ns, head.escalate, head.escalated_runs = change_ns, True, 0
                head.drifts += 1
                found.append(Drift(head, change_ns, int(t_end), mon, version))
                head.retired.clear()  # one change, one event: every reference of this output predates it
                if head.monitor is not None:
                    head.monitor.spend()
                break
        for w in list(head.retired):
            if w.monitor is mon:
                w.blocks_left -= n_blocks
                if w.blocks_left <= 0:
                    head.retired.remove(w)
    return found
