"""The daemon's side of stream sharing on the bus: its tokens, the others' tokens, and handed-over state.

:class:`ShareLink` adapts :class:`~streamid.daemon.sharing.Shares` (the rules, no I/O)
to a :class:`~streamid.transport.Bus`:

* it watches every member and claim token (liveliness subscriptions with history),
* declares this daemon's member token once ``join_after_s`` has passed, and its claim
  tokens as :meth:`Shares.step` says,
* keeps the newest state the serving daemon put on ``streamid/@state/<s>`` for each
  stream this daemon owns or stands by for (at most ``max_streams`` entries of at most
  ``max_payload_bytes`` each: only daemons may publish there, see
  ``examples/zenoh/router.json5``, and what they send is bounded all the same),
* and puts this daemon's state of a stream it serves there (:meth:`hand_off`).

Without access control (the trusted-network variant) anyone who reaches the router can declare a
member or claim token and so take this daemon's streams: :meth:`start` warns when the daemon
shares on a session whose configuration neither enforces access control nor authenticates to a
router (the shipped recipe: ``examples/zenoh/router.json5`` + ``daemon-via-router.json5``) and may be reached
from other machines (it connects to a router or listens beyond loopback; the default daemon, on loopback alone, is
reached from this machine only and says nothing), and
:meth:`successor_check` makes a hand-over to a daemon that never put a state on
``streamid/@state/*`` a WARNING naming it (a daemon that just joined, or a forged token).

The daemon calls :meth:`tick` from its housekeeping thread; ``serve`` and ``release``
actions come back to it (declare or close the stream's publishers, restore the
handed-over state).
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from streamid.daemon.sharing import MAX_LIVES, Action, Life, Shares
from streamid.errors import ModelFormatError
from streamid.online.snapshot import StreamState
from streamid.transport import Bus
from streamid.wire.keys import CLAIMS_ALL, HANDOFF_ALL, MEMBERS_ALL, claim_key, handoff_key, member_key, parse_life_key

__all__ = ["ShareLink"]

_log = logging.getLogger("streamid.daemon.service")
#: The daemon id in a handed-over state's model message (``"origin": {"daemon": ...``).
_ORIGIN_RE = re.compile(rb'"origin"\s*:\s*\{\s*"daemon"\s*:\s*"([A-Za-z0-9_.\-]{1,128})"')
#: What the start warning and the hand-over warning name as the way to prevent a stolen stream.
RECIPE = ("run the router with examples/zenoh/router.json5 and each daemon with examples/zenoh/daemon-via-router.json5 "
          "(access control: only the 'daemon' user may declare streamid/@daemons, streamid/@claims and put "
          "streamid/@state; docs/security.md, 'With a Zenoh router')")


def _endpoints(config: Any, key: str) -> list[str]:
    """The endpoints of ``key`` (``connect/endpoints`` or ``listen/endpoints``: a list, or a dict of lists by mode)."""
    try:
        value = json.loads(config.get_json(key) or "[]")
    except Exception:  # noqa: BLE001 - a key this Zenoh does not know, or not JSON: none
        return []
    if isinstance(value, dict):
        return [str(e) for v in value.values() if isinstance(v, list) for e in v]
    return [str(e) for e in value] if isinstance(value, list) else []


def _loopback(endpoint: str) -> bool:
    """Whether an endpoint such as ``tcp/127.0.0.1:7447`` or ``tcp/[::1]:7447`` names this machine only."""
    host = endpoint.split("/", 1)[-1].split("#", 1)[0].rsplit(":", 1)[0].strip("[]")
    return host in ("localhost", "::1") or host.startswith("127.")


def reaches_others(config: Any) -> bool:
    """Whether a session may be reached from other machines: it connects to anything (a router, which others reach
    too) or listens on an endpoint that is not loopback. A daemon listening on loopback alone (the default) is
    reached from this machine only."""
    return bool(_endpoints(config, "connect/endpoints")) or any(
        not _loopback(e) for e in _endpoints(config, "listen/endpoints"))


def unprotected(config: Any) -> bool:
    """Whether a session configuration (a ``zenoh.Config``) neither enforces access control nor authenticates."""
    try:
        acl = config.get_json("access_control/enabled")
        user = config.get_json("transport/auth/usrpwd/user")
    except Exception:  # noqa: BLE001 - a key this Zenoh does not know: nothing configured there
        return True
    return acl != "true" and user in (None, "null", '""')


class ShareLink:
    """Tokens and handed-over state of one daemon (see the module docstring)."""

    def __init__(self, shares: Shares, *, join_after_s: float, max_streams: int, max_payload_bytes: int) -> None:
        self.shares = shares
        self.join_after_s = float(join_after_s)
        self.max_streams = int(max_streams)
        self.max_payload_bytes = int(max_payload_bytes)
        self.counters: Counter[str] = Counter()
        self._bus: Bus | None = None
        self._handles: list[Any] = []
        self._member: Any | None = None
        self._claims: dict[str, Any] = {}
        self._handoff: dict[str, bytes] = {}
        self._lock = threading.Lock()
        self._started = 0.0
        self._stated: set[str] = set()  # daemons seen putting a state on streamid/@state/* (at most MAX_LIVES)
        self._warned_successors: set[str] = set()

    @property
    def me(self) -> Life:
        return self.shares.me

    def start(self, bus: Bus) -> None:
        """Watch the tokens and the handed-over states; the member token follows after ``join_after_s``."""
        self._bus = bus
        self._started = time.monotonic()
        self._handles.append(bus.liveliness_subscribe(MEMBERS_ALL, self._on_token))
        self._handles.append(bus.liveliness_subscribe(CLAIMS_ALL, self._on_token))
        self._handles.append(bus.subscribe(HANDOFF_ALL, self._on_handoff, max_payload_bytes=self.max_payload_bytes,
                                           on_too_large=lambda _k, _n: self.counters.update(["handoff_too_large"])))
        config = bus.settings.to_config()
        if self.shares.share and unprotected(config) and reaches_others(config):
            _log.warning("stream sharing on a bus without access control: anyone who reaches the router can declare "
                         "a member (streamid/@daemons/...) or a claim (streamid/@claims/...) and take this daemon's "
                         "streams, or hand it a state; to prevent it, %s", RECIPE)

    def _on_token(self, key: str, alive: bool) -> None:
        parsed = parse_life_key(key)
        if parsed is None:
            self.counters["tokens_malformed"] += 1
            return
        stream, daemon, epoch = parsed
        life = Life(daemon, epoch)
        if stream is None:
            self.shares.member(life, alive)
        else:
            self.shares.claim(stream, life, alive)

    def _on_handoff(self, key: str, payload: bytes) -> None:
        stream = key.rsplit("/", 1)[-1]
        m = _ORIGIN_RE.search(payload)
        if m is not None and len(self._stated) < MAX_LIVES:
            self._stated.add(m.group(1).decode("ascii"))
        if self.shares.role(stream) == "none" or self.shares.serving(stream):
            return  # not ours to take over (or our own put coming back)
        with self._lock:
            if stream not in self._handoff and len(self._handoff) >= self.max_streams:
                self.counters["handoff_refused"] += 1
                return
            self._handoff[stream] = payload
        self.counters["handoff_received"] += 1

    # ------------------------------------------------------------------ each housekeeping tick
    def tick(self, streams: list[str], on_serve: Callable[[str], None], on_release: Callable[[str], None],
             now_ns: int | None = None) -> None:
        """Join when due, advance the phases; claims declared and withdrawn, ``on_serve``/``on_release`` called, in order."""
        bus = self._bus
        if bus is None:
            return
        if self.shares.share and self._member is None and self._join_due():
            self._member = bus.liveliness_token(member_key(self.me.daemon, self.me.epoch_ns))
            with self.shares.lock:
                self.shares.joined = True
            _log.info("stream sharing: joined as daemon %s (members now: %s)", self.me.daemon,
                      ", ".join(self.shares.members()))
        actions = self.shares.step(streams, time.time_ns() if now_ns is None else now_ns)
        self._apply(actions, on_serve, on_release)

    def _join_due(self) -> bool:
        """Join at once when alone (once the tokens alive before us had time to arrive), else after ``join_after_s``."""
        waited = time.monotonic() - self._started
        if waited < self.shares.settle_ns / 1e9:
            return False
        alone = all(d == self.me.daemon for d in self.shares.members())
        return alone or waited >= self.join_after_s

    def forget(self, stream: str, on_release: Callable[[str], None]) -> None:
        """A stream's slot is gone: stop serving it (``on_release``) and withdraw its claim."""
        self._apply(self.shares.forget(stream), lambda _s: None, on_release)

    def _apply(self, actions: list[Action], on_serve: Callable[[str], None], on_release: Callable[[str], None]) -> None:
        bus = self._bus
        for act in actions:
            if act.kind == "claim" and bus is not None and act.stream not in self._claims:
                self._claims[act.stream] = bus.liveliness_token(claim_key(act.stream, self.me.daemon, self.me.epoch_ns))
            elif act.kind == "unclaim":
                handle = self._claims.pop(act.stream, None)
                if handle is not None:
                    handle.close()
            elif act.kind == "serve":
                on_serve(act.stream)
            elif act.kind == "release":
                on_release(act.stream)

    # ------------------------------------------------------------------ state for the next owner
    def take_handoff(self, stream: str) -> StreamState | None:
        """The newest state of ``stream`` put by its previous owner (None: none, or unreadable: counted)."""
        with self._lock:
            payload = self._handoff.pop(stream, None)
        if payload is None:
            return None
        try:
            state = StreamState.from_json(payload.decode("utf-8"), source=f"the state handed over on {handoff_key(stream)}")
        except (ModelFormatError, UnicodeDecodeError, ValueError) as exc:
            self.counters["handoff_unreadable"] += 1
            _log.warning("stream %s: handed-over state unreadable (%s); resuming from this daemon's own state", stream, exc)
            return None
        if state.stream != stream:
            self.counters["handoff_unreadable"] += 1
            return None
        return state

    def successor_check(self, stream: str) -> list[str]:
        """At a hand-over of ``stream``: the daemons it goes to (a beating claim's, else the assigned owner) that
        never put a state here; each is named in one WARNING per daemon life of ours (a daemon that just joined,
        or a token anyone could declare on a bus without access control)."""
        to = sorted({lf.daemon for lf in self.shares.claimants(stream) if lf.daemon != self.me.daemon})
        owner = self.shares.owner(stream)
        if not to and owner is not None and owner != self.me.daemon:
            to = [owner]
        fresh = [d for d in to if d not in self._stated]
        for d in fresh:
            self.counters["handed_to_unknown"] += 1
            if d not in self._warned_successors and len(self._warned_successors) < MAX_LIVES:
                self._warned_successors.add(d)
                _log.warning("stream %s: handed over to daemon %r, which never put a state on streamid/@state/*: "
                             "a daemon that just joined, or a member or claim token declared by someone else (on a "
                             "bus without access control anyone can); to prevent it, %s", stream, d, RECIPE)
        return fresh

    def has_successor(self) -> bool:
        """Whether another daemon may take a stream over (a state is worth putting): another member lives,
        or this daemon is not a member (a daemon waiting on the same ``--stream`` cannot be seen)."""
        return not self.shares.share or any(d != self.me.daemon for d in self.shares.members())

    def hand_off(self, stream: str, state_json: str) -> None:
        """Put this daemon's state of ``stream`` for whoever serves it next (before the model it goes with)."""
        bus = self._bus
        if bus is None:
            return
        try:
            bus.put(handoff_key(stream), state_json.encode("utf-8"), block=True)
            self.counters["handoff_sent"] += 1
        except Exception as exc:  # noqa: BLE001 - the model is still published
            self.counters["handoff_errors"] += 1
            _log.warning("stream %s: state not handed off (%s)", stream, exc)

    def info(self) -> dict[str, Any]:
        """The sharing part of the daemon's status."""
        return {
            "sharing": self.shares.share,
            "members": self.shares.members(),
            "serving": self.shares.served(),
            **{k: int(v) for k, v in self.counters.items() if v},
        }

    def close(self) -> None:
        """Withdraw every token and subscription (the session closing does it too)."""
        for handle in [*self._handles, *self._claims.values(), *([self._member] if self._member else [])]:
            try:
                handle.close()
            except Exception:  # noqa: BLE001
                pass
        self._handles.clear()
        self._claims.clear()
        self._member = None
