"""The daemon's slots as streams come, move to another daemon and go (a part of :class:`~streamid.daemon.service.Daemon`).

A stream's publishers and queryables (``model``, ``status``, ``rejected``) exist only while
this daemon serves it (:mod:`streamid.daemon.sharing`): declared on ``serve``, closed on
``release``; a discovered stream that another daemon serves and another stands by for, or
that sent no valid sample for ``stream_idle_s``, gives its slot back.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from typing import TYPE_CHECKING, Any

from streamid.daemon.slots import StreamSlot as _Stream
from streamid.daemon.slots import forward_events
from streamid.daemon.versions import MAX_VERSION_STEP, within_step
from streamid.wire.documents import encode_json
from streamid.wire.keys import model_key, rejected_key, status_key

if TYPE_CHECKING:
    from streamid.daemon.config import DaemonConfig
    from streamid.daemon.runner import JobRunner
    from streamid.daemon.share_link import ShareLink
    from streamid.daemon.sharing import Shares
    from streamid.daemon.state_store import StateStore
    from streamid.daemon.versions import VersionKeeper
    from streamid.transport import Bus

__all__ = ["SlotKeeping"]

_log = logging.getLogger("streamid.daemon.service")


class SlotKeeping:
    """Declaring, serving, handing over and releasing stream slots (mixed into the daemon)."""

    config: DaemonConfig
    bus: Bus | None
    viz: Any | None
    identify: bool
    versions: VersionKeeper
    store: StateStore | None
    shares: Shares
    link: ShareLink
    _streams: dict[str, _Stream]
    _streams_lock: threading.Lock
    _pubs: dict[str, Any]
    _global: Counter[str]
    _runner: JobRunner

    def _status(self, st: _Stream) -> dict[str, Any]:
        raise NotImplementedError

    def _declare(self, st: _Stream) -> None:
        """Publishers and queryables of one stream (housekeeping thread or start)."""
        bus, name = self.bus, st.ident.stream
        if st.declared or bus is None:
            return
        self._pubs[f"{name}/model"] = bus.publisher(model_key(name), block=True)
        self._pubs[f"{name}/status"] = bus.publisher(status_key(name), block=False)
        self._pubs[f"{name}/rejected"] = bus.publisher(rejected_key(name), block=False)
        st.handles += [self._pubs[f"{name}/{k}"] for k in ("model", "status", "rejected")]

        def model_reply(_key: str) -> list[bytes]:
            with st.lock:
                return list(st.ident.payloads)  # the champion of every output: one reply each

        def status_reply(_key: str) -> bytes | None:
            return encode_json(self._status(st))

        st.handles += [bus.queryable(model_key(name), model_reply), bus.queryable(status_key(name), status_reply)]
        st.declared = True

    def _serve(self, name: str) -> None:
        """This daemon serves ``name`` from now on: resume from the handed-over state if newer, declare, wake."""
        st = self._streams.get(name)
        if st is None:
            return
        state = self.link.take_handoff(name)
        with st.lock:
            if state is not None and not within_step(state.version, st.ident.version):
                # a version beyond the bounded step: a forged or replayed state does not move this daemon's
                self.link.counters["handoff_version_refused"] += 1
                _log.warning("stream %s: the state handed over is at v%d, more than %d (MAX_VERSION_STEP) above this "
                             "daemon's v%d: not taken (forged or replayed?); resuming from this daemon's own state",
                             name, state.version, MAX_VERSION_STEP, st.ident.version)
                state = None
            if state is not None and state.version > st.ident.version:
                for warning in st.ident.restore(state):
                    _log.warning("stream %s: %s", name, warning)
                self.versions.settled(name)  # the handed-over version is the network's
                _log.info("stream %s: taken over at v%d (state handed over by the previous owner)", name, state.version)
            due = st.ident.pending > 0
        try:
            self._declare(st)
        except Exception as exc:  # noqa: BLE001
            _log.error("stream %s: declarations failed (%s)", name, exc)
        _log.info("stream %s: served by this daemon (%s)", name, self.versions.origin.daemon)
        if due and self.identify:
            self._runner.wake(name)

    def _release(self, name: str) -> None:
        """Another daemon serves ``name`` now (nothing is published from here on): hand the state over, close.

        Called before the claim is withdrawn, so the next owner has the newest state (and version) first.
        """
        st = self._streams.get(name)
        if st is not None:
            with st.lock:
                state = st.ident.state(now_ns=time.time_ns()).to_json() if st.ident.version > 0 else None
            if state is not None:
                self.link.hand_off(name, state)
            self._undeclare(st)
            self.link.successor_check(name)
        _log.info("stream %s: handed over (members: %s)", name, ", ".join(self.shares.members()) or "none")

    def _undeclare(self, st: _Stream) -> None:
        name = st.ident.stream
        for key in (f"{name}/model", f"{name}/status", f"{name}/rejected"):
            if any(self._pubs.get(key) is h for h in st.handles):
                self._pubs.pop(key, None)
        for h in st.handles:
            try:
                h.close()
            except Exception:  # noqa: BLE001 - the session may be closing
                pass
        st.handles.clear()
        st.declared = False

    def _release_idle(self, now: float) -> None:
        """Give back the slots of discovered streams without a valid sample for ``stream_idle_s``."""
        for st in list(self._streams.values()):
            with st.lock:
                samples = st.ident.counters().get("samples_in", 0)
                if samples != st.samples_seen:
                    st.samples_seen, st.valid_mono = samples, now
                    continue
                elsewhere = self.shares.role(st.ident.stream) == "none" and not self.shares.serving(st.ident.stream)
                if st.configured or st.ident.busy or (now - st.valid_mono < self.config.stream_idle_s and not elsewhere):
                    continue
            with self._streams_lock:
                if self._streams.get(st.ident.stream) is not st:
                    continue
                del self._streams[st.ident.stream]
                self._global["streams_released"] += 1
            self._close_slot(st, "served and stood by for by other daemons" if elsewhere else
                             f"{now - st.valid_mono:.0f} s without a valid sample (daemon.stream_idle_s = "
                             f"{self.config.stream_idle_s:g})")

    def _close_slot(self, st: _Stream, why: str) -> None:
        """Close the declarations of a slot already removed from the table (housekeeping thread)."""
        name = st.ident.stream
        if name not in self._streams:  # (not already back in a new slot)
            self._runner.scheduler.forget(name)
            self.link.forget(name, lambda _s: None)  # no publish from here on; the claim is withdrawn
        self._undeclare(st)
        forward_events(st, self.viz)
        _log.info("stream %s: slot released: %s%s", name, why, "; its state file stays" if self.store is not None else "")
