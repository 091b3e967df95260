"""Which daemon serves which stream: membership, rendezvous hashing and claims (no I/O).

Several daemons connected to one Zenoh network divide the streams among themselves
with no coordinator of their own; Zenoh's liveliness tokens carry everything
(:mod:`streamid.daemon.share_link` declares and watches them):

* **Members.**  A sharing daemon (discovering streams, ``daemon.share = true``) holds
  a token ``streamid/@daemons/<id>/<epoch>`` for its life.  Zenoh withdraws it when
  the process dies (its TCP connection closes) or its link is silent for the lease.
* **Assignment.**  Stream ``s`` belongs to the live member with the highest
  rendezvous score ``blake2b(s, id)``: every daemon computes the same owner from the
  same member set; a member joining or leaving moves only its own share; when the
  owner dies, the stream goes to the member that ranked second, which is the one that
  kept a *standby* copy of the stream's window (it buffers the samples, never
  identifies) and of the owner's state (``streamid/@state/<s>``): it resumes warm.
* **Claims.**  Before serving ``s`` a daemon declares ``streamid/@claims/<s>/<id>/<epoch>``
  and waits ``claim_settle_s`` for another claim to show; it serves only while no
  other live claim *beats* its own (the higher rendezvous score of the two daemon
  ids, then the later epoch).  A daemon that must hand a stream over stops
  publishing first (under the lock that every publish holds), then withdraws
  its claim; the next owner claims only once no other claim is alive.  So two daemons
  never publish one stream at the same time, as long as a withdrawn or lost claim
  reaches the next owner after the last put of the previous one (the same
  session sends both, in that order, through the same router).  A daemon started
  with ``--stream`` claims its streams the same way without being a member: two such
  daemons on one stream make one serve and the other wait, buffering.

A new member first buffers the streams it will own for ``join_after_s`` (so a
stream it takes over has a full window) and only then declares its member token.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

__all__ = ["Life", "Shares", "Action", "score", "ranking", "beats", "Role"]

Role = Literal["owner", "standby", "none"]
#: Bounds on what the liveliness tokens of others can make a daemon remember.
MAX_LIVES = 4096
MAX_CLAIMS = 65_536


@dataclass(frozen=True, order=True)
class Life:
    """One life of a daemon: its id (stable per state directory) and the start of this life (unix ns)."""

    daemon: str
    epoch_ns: int


@dataclass(frozen=True)
class Action:
    """What the adapter must do for a stream: ``claim``, ``unclaim``, ``serve`` or ``release``."""

    kind: Literal["claim", "unclaim", "serve", "release"]
    stream: str


def score(stream: str, daemon: str) -> int:
    """Rendezvous score of ``daemon`` for ``stream`` (64 bits of BLAKE2b: the same on every machine)."""
    h = hashlib.blake2b(f"{stream}\x00{daemon}".encode(), digest_size=8)
    return int.from_bytes(h.digest(), "big")


def ranking(stream: str, daemons: Iterable[str]) -> list[str]:
    """Daemon ids best first for ``stream`` (ties, which BLAKE2b makes vanishingly rare, by id)."""
    return sorted(set(daemons), key=lambda d: (-score(stream, d), d))


def beats(a: Life, b: Life, stream: str) -> bool:
    """Whether claim ``a`` wins over claim ``b`` on ``stream``: higher score, then the later life of one daemon."""
    return (score(stream, a.daemon), a.epoch_ns) > (score(stream, b.daemon), b.epoch_ns)


class Shares:
    """The sharing state of one daemon: members, claims, and the phase of each stream it may serve.

    Parameters
    ----------
    me
        This daemon's life.
    share
        Whether this daemon is a member (divides discovered streams with the others).
        False: it serves every stream it may (its ``--stream`` list, or all it
        discovers) but still claims each before serving it.
    explicit
        Streams named in the configuration: served whatever the assignment says
        (claims still decide between two daemons naming the same stream).
    settle_ns
        How long a new claim must stand unbeaten before the stream is served.

    Thread-safe: Zenoh's callbacks report tokens, the housekeeping thread calls
    :meth:`step`, the receiving and worker threads ask :meth:`role` and
    :meth:`serving`.  ``publish_lock`` is held by every publish of a served stream
    and by :meth:`step` and :meth:`forget`, which turn ``serving`` off under it
    (lock order: ``publish_lock``, then ``lock``).
    """

    def __init__(self, me: Life, *, share: bool, explicit: Iterable[str] = (), settle_ns: int = 300_000_000) -> None:
        self.me = me
        self.share = bool(share)
        self.explicit = frozenset(explicit)
        self.settle_ns = int(settle_ns)
        self.joined = False  # our member token is declared (set by the adapter)
        self.lock = threading.RLock()
        self.publish_lock = threading.Lock()  # held by every publish of a served stream, and to stop serving one
        self._lives: set[Life] = set()
        self._claims: dict[str, set[Life]] = {}
        self._n_claims = 0
        self._phase: dict[str, tuple[str, int]] = {}  # stream -> ("claiming" | "serving", since_ns)
        self.ignored = 0  # tokens not remembered: over the bounds

    # ------------------------------------------------------------------ tokens
    def member(self, life: Life, alive: bool) -> None:
        """A member token appeared (``alive``) or vanished."""
        with self.lock:
            if not alive:
                self._lives.discard(life)
            elif len(self._lives) < MAX_LIVES:
                self._lives.add(life)
            else:
                self.ignored += 1

    def claim(self, stream: str, life: Life, alive: bool) -> None:
        """A claim token on ``stream`` appeared or vanished."""
        with self.lock:
            held = self._claims.get(stream)
            if not alive:
                if held is not None and life in held:
                    held.discard(life)
                    self._n_claims -= 1
                    if not held:
                        del self._claims[stream]
                return
            if self._n_claims >= MAX_CLAIMS:
                self.ignored += 1
                return
            held = self._claims.setdefault(stream, set())
            if life not in held:
                held.add(life)
                self._n_claims += 1

    # ------------------------------------------------------------------ questions
    def members(self) -> list[str]:
        """Ids of the live members (this daemon once it joined), sorted."""
        with self.lock:
            ids = {lf.daemon for lf in self._lives}
            if self.joined and self.share:
                ids.add(self.me.daemon)
            return sorted(ids)

    def _ranked(self, stream: str) -> list[str]:
        ids = {lf.daemon for lf in self._lives}
        ids.add(self.me.daemon)  # before joining too: which streams to buffer ahead
        return ranking(stream, ids)

    def role(self, stream: str) -> Role:
        """``owner``: this daemon should serve it; ``standby``: it keeps the window for the owner's successor."""
        with self.lock:
            if stream in self.explicit or not self.share:
                return "owner"
            ranked = self._ranked(stream)
            if ranked[0] == self.me.daemon:
                return "owner"
            return "standby" if len(ranked) > 1 and ranked[1] == self.me.daemon else "none"

    def owner(self, stream: str) -> str | None:
        """The member that should serve ``stream`` (None: not a sharing setup)."""
        with self.lock:
            if not self.share:
                return None
            return self._ranked(stream)[0]

    def serving(self, stream: str) -> bool:
        """Whether this daemon serves ``stream`` now (publishes its models)."""
        with self.lock:
            return self._phase.get(stream, ("", 0))[0] == "serving"

    def keeps_windows(self, stream: str) -> bool:
        """Whether closed windows of ``stream`` wait here to be identified (else a standby skips them).

        True while this daemon claims or serves it, and when it is about to: it owns the
        stream and has joined, or no other member is known (a lone daemon's first windows).
        """
        with self.lock:
            if stream in self._phase:
                return True
            alone = all(lf.daemon == self.me.daemon for lf in self._lives)
            return self.role(stream) == "owner" and (self.joined or alone or not self.share)

    def served(self) -> list[str]:
        """The streams served now."""
        with self.lock:
            return sorted(s for s, (p, _) in self._phase.items() if p == "serving")

    def claimants(self, stream: str) -> list[Life]:
        """The live claims on ``stream`` (this daemon's included)."""
        with self.lock:
            return sorted(self._claims.get(stream, ()))

    # ------------------------------------------------------------------ the state machine
    def _wanted(self, stream: str) -> bool:
        if stream in self.explicit or not self.share:
            return True
        return self.joined and self._ranked(stream)[0] == self.me.daemon

    def step(self, streams: Iterable[str], now_ns: int) -> list[Action]:
        """Advance every stream's phase; returns the actions for the adapter, in order."""
        out: list[Action] = []
        with self.publish_lock, self.lock:
            for s in list(dict.fromkeys([*streams, *self._phase])):
                phase, since = self._phase.get(s, ("idle", 0))
                others = [lf for lf in self._claims.get(s, ()) if lf != self.me]
                beaten = any(beats(lf, self.me, s) for lf in others)
                wanted = self._wanted(s)
                if phase == "idle":
                    if wanted and not others:
                        self._phase[s] = ("claiming", now_ns)
                        out.append(Action("claim", s))
                elif phase == "claiming":
                    if not wanted or beaten:
                        del self._phase[s]
                        out.append(Action("unclaim", s))
                    elif now_ns - since >= self.settle_ns:
                        self._phase[s] = ("serving", now_ns)
                        out.append(Action("serve", s))
                elif not wanted or beaten:  # serving
                    del self._phase[s]  # no publish from here on (publish_lock is held)
                    out += [Action("release", s), Action("unclaim", s)]
        return out

    def forget(self, stream: str) -> list[Action]:
        """The stream's slot is gone: stop serving and withdraw the claim."""
        with self.publish_lock, self.lock:
            phase = self._phase.pop(stream, ("idle", 0))[0]
        if phase == "serving":
            return [Action("release", stream), Action("unclaim", stream)]
        return [Action("unclaim", stream)] if phase == "claiming" else []
