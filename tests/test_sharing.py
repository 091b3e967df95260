"""Daemons dividing streams among themselves: the rules (rendezvous, claims), then real daemons behind a router.

The end-to-end test runs a real ``streamid router`` and two real ``streamid daemon``
processes (each connected only to the router, default mode, no ``--stream``), four
streams replayed in real time, and a raw subscriber of every model document.  It
SIGKILLs a daemon, checks that its streams resume on the survivor within 5 s, warm
(versions continue above the dead owner's), and that the killed daemon, started
again on its state directory, takes its share back.  Through all of it, every
stream's versions strictly increase in the order they arrive and each stream's
publisher changes only at those hand-overs: no two daemons ever publish one stream
at once.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any


from conftest import STREAMID, endpoint
from replay.player import ReplayConfig, replay_log
from streamid.daemon.sharing import Action, Life, Shares, beats, ranking, score
from streamid.logs.bundled import bundled_log
from streamid.transport import Bus, ZenohSettings


# ----------------------------------------------------------------------------- the rules
def test_rendezvous_is_deterministic_and_moves_only_the_leaving_members_share() -> None:
    streams = [f"s{i}" for i in range(400)]
    three = {s: ranking(s, ["a", "b", "c"]) for s in streams}
    assert three == {s: ranking(s, ["c", "a", "b"]) for s in streams}  # order of discovery does not matter
    counts = {d: sum(r[0] == d for r in three.values()) for d in "abc"}
    assert min(counts.values()) > 90, counts  # ~133 each
    two = {s: ranking(s, ["a", "b"]) for s in streams}
    for s in streams:
        if three[s][0] != "c":
            assert two[s][0] == three[s][0]  # c leaving moves only c's streams ...
        else:
            assert two[s][0] == three[s][1]  # ... each to the member that ranked second: its standby
    assert score("x", "a") == score("x", "a") and score("x", "a") != score("y", "a")


def test_beats_is_a_strict_order_and_a_later_life_of_one_daemon_wins() -> None:
    a, b, a2 = Life("a", 1), Life("b", 1), Life("a", 2)
    for s in ("s1", "s2", "s3"):
        assert beats(a, b, s) != beats(b, a, s)
        assert beats(a2, a, s) and not beats(a, a2, s)


def _step(sh: Shares, streams: list[str], t_s: float) -> list[tuple[str, str]]:
    return [(a.kind, a.stream) for a in sh.step(streams, int(t_s * 1e9))]


def test_a_claim_is_served_after_it_stood_unbeaten_and_released_when_beaten_or_not_wanted() -> None:
    me, other = Life("me", 1), Life("other", 1)
    s = next(n for n in (f"s{i}" for i in range(100)) if ranking(n, ["me", "other"])[0] == "me")
    sh = Shares(me, share=True, settle_ns=300_000_000)
    assert _step(sh, [s], 0.0) == []  # not joined yet: nothing claimed
    sh.joined = True
    assert _step(sh, [s], 0.0) == [("claim", s)]
    sh.claim(s, me, True)
    assert _step(sh, [s], 0.1) == [] and not sh.serving(s)  # settling
    assert _step(sh, [s], 0.35) == [("serve", s)] and sh.serving(s)
    sh.member(other, True)  # a member that ranks lower for s: nothing moves
    assert _step(sh, [s], 0.4) == [] and sh.serving(s)
    assert sh.role(s) == "owner"
    t = next(n for n in (f"t{i}" for i in range(100)) if ranking(n, ["me", "other"])[0] == "other")
    assert sh.role(t) == "standby" and _step(sh, [t], 0.5) == []  # other's stream: never claimed here
    # a claim by a life that beats ours makes us let go, at once
    winner = next(Life(f"w{i}", 1) for i in range(100) if beats(Life(f"w{i}", 1), me, s))
    sh.claim(s, winner, True)
    assert _step(sh, [s], 0.6) == [("release", s), ("unclaim", s)] and not sh.serving(s)
    sh.claim(s, me, False)
    assert _step(sh, [s], 0.7) == []  # another claim is alive: wait
    sh.claim(s, winner, False)
    assert _step(sh, [s], 0.8) == [("claim", s)]


def test_a_daemon_with_explicit_streams_claims_them_without_being_a_member() -> None:
    sh = Shares(Life("solo", 1), share=False, explicit=["x"], settle_ns=0)
    assert sh.members() == [] and sh.role("x") == "owner"
    assert _step(sh, ["x"], 0.0) == [("claim", "x")]
    assert _step(sh, ["x"], 0.0) == [("serve", "x")]
    assert sh.forget("x") == [Action("release", "x"), Action("unclaim", "x")]


# ----------------------------------------------------------------------------- real daemons
CONFIG = """
[daemon]
join_after_s = 2.0
claim_settle_s = 0.3
status_every_s = 0.5
helper = false

[defaults]
window_s = 2.0
update_every_s = 0.5
cold_generations = 30
warm_generations = 8
neurons = 5
max_lag_y = 3
max_lag_u = 3
challenger_margin = -1.0
"""


def _daemon(tmp: Path, name: str, ep: str) -> subprocess.Popen[str]:
    state = tmp / name
    state.mkdir(exist_ok=True)
    ident = state / "daemon.identity"
    if not ident.exists():  # a chosen id, so the test knows the assignment in advance
        ident.write_text(json.dumps({"format": "streamid.daemon-identity/1", "daemon": name, "last_epoch_ns": 0}))
    cfg = tmp / "daemon.toml"
    cfg.write_text(CONFIG)
    log = open(tmp / f"{name}.log", "a")
    return subprocess.Popen([*STREAMID, "daemon", "--connect", ep, "--config", str(cfg), "--state-dir", str(state),
                             "--no-rerun", "-v"], stdout=log, stderr=log, text=True)


def _wait(cond: Any, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return bool(cond())


def other(daemon: str) -> str:
    return "beta" if daemon == "alpha" else "alpha"


def _runs(seq: list[str]) -> list[str]:
    out: list[str] = []
    for x in seq:
        if not out or out[-1] != x:
            out.append(x)
    return out


def test_two_daemons_share_fail_over_warm_and_take_their_share_back(tmp_path: Path) -> None:
    ep = endpoint()
    names = [f"dev{i}" for i in range(40)]
    mine = {d: [s for s in names if ranking(s, ["alpha", "beta"])[0] == d][:2] for d in ("alpha", "beta")}
    streams = mine["alpha"] + mine["beta"]
    router = subprocess.Popen([*STREAMID, "router", "--listen", ep], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    got: list[tuple[float, str, int, str]] = []  # (receive time, stream, version, daemon)
    lock = threading.Lock()
    stop = threading.Event()
    procs: dict[str, subprocess.Popen[str]] = {}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus:
            def on_model(key: str, payload: bytes) -> None:
                doc = json.loads(payload)
                with lock:
                    got.append((time.monotonic(), doc["stream"], doc["version"], doc["origin"]["daemon"]))

            bus.subscribe("streamid/*/model", on_model)
            procs["alpha"] = _daemon(tmp_path, "alpha", ep)
            procs["beta"] = _daemon(tmp_path, "beta", ep)
            players = [threading.Thread(target=replay_log, args=(bundled_log("mr_damper.mcap"),),
                                        kwargs={"bus": bus, "stop_event": stop, "config": ReplayConfig(
                                            loops=20, stream_map=(("mr_damper", s),), wait_subscribers_s=20.0)},
                                        daemon=True) for s in streams]
            for p in players:
                p.start()

            def last_from(stream: str, daemon: str, after: float) -> bool:
                with lock:
                    return any(s == stream and d == daemon and t > after for t, s, _, d in got)

            # 1. each daemon serves its share (after beta joined, alpha handed beta's streams over)
            assert _wait(lambda: all(last_from(s, d, 0) for d in mine for s in mine[d]), 40), got[-10:]
            t_split = time.monotonic()
            assert _wait(lambda: all(last_from(s, d, t_split) for d in mine for s in mine[d]), 10)
            # Health is per window: a window across the looped log's seam can fail the floors (the state says
            # DEGRADED with the reason) until the next model is accepted; every stream must be shown healthy at
            # one reading within 20 s (seen on a slower machine: one stream degraded at the first reading).
            shown_last: list[subprocess.CompletedProcess[str]] = []

            def all_served_and_healthy() -> bool:
                shown = subprocess.run([*STREAMID, "status", "--connect", ep], capture_output=True, text=True,
                                       timeout=30)
                shown_last[:] = [shown]
                assert shown.returncode == 0, shown.stderr
                rows = {ln.split()[0]: ln.split()[1] for ln in shown.stdout.splitlines()[1:]}
                assert rows == {s: d for d in mine for s in mine[d]}, shown.stdout  # who serves which stream
                return all(" 2  " in ln and ln.endswith("ok") for ln in shown.stdout.splitlines()[1:])

            assert _wait(all_served_and_healthy, 20), shown_last[0].stdout
            # 2. SIGKILL beta: its streams resume on alpha, warm
            procs["beta"].send_signal(signal.SIGKILL)
            procs["beta"].wait(10)
            t_kill = time.monotonic()
            with lock:
                beta_last = {s: max(v for _, ss, v, d in got if ss == s) for s in mine["beta"]}
            assert _wait(lambda: all(last_from(s, "alpha", t_kill) for s in mine["beta"]), 15)
            with lock:
                resumed = {s: min(t for t, ss, _, d in got if ss == s and d == "alpha" and t > t_kill) - t_kill
                           for s in mine["beta"]}
                first_v = {s: min(v for t, ss, v, d in got if ss == s and d == "alpha" and t > t_kill)
                           for s in mine["beta"]}
            # How soon (`resumed`, seconds) is the bench's figure, not a test's (issue 39 item 5: a wall-clock time
            # of this machine under load is no assertion): examples/measure/scale.py failover, docs/benchmarks.md.
            assert all(first_v[s] == beta_last[s] + 1 for s in mine["beta"]), (first_v, beta_last, resumed)  # warm
            # 3. beta comes back on its state directory (same id, new life) and takes its share again
            t_back = time.monotonic()
            procs["beta"] = _daemon(tmp_path, "beta", ep)
            assert _wait(lambda: all(last_from(s, "beta", t_back) for s in mine["beta"]), 30)
            t_end = time.monotonic()
            assert _wait(lambda: all(last_from(s, d, t_end) for d in mine for s in mine[d]), 10)
            stop.set()  # the players end while their bus is open (else a put meets an undeclared publisher)
            for p in players:
                p.join(10)
    finally:
        stop.set()
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
        router.terminate()
        router.wait(10)
    by_stream: dict[str, list[tuple[float, int, str]]] = defaultdict(list)
    for t, s, v, d in sorted(got):
        by_stream[s].append((t, v, d))
    for s in streams:
        versions = [v for _, v, _ in by_stream[s]]
        assert versions == sorted(set(versions)), (s, versions)  # strictly increasing: never two publishers
        owner = "alpha" if s in mine["alpha"] else "beta"
        # at the start, whichever daemon came up first served everything until the other joined: one hand-over at most
        start = _runs([d for t, _, d in by_stream[s] if t < t_split])
        assert start in ([owner], [other(owner), owner]), (s, start)
        later = _runs([d for t, _, d in by_stream[s] if t >= t_split])  # beta's streams: alpha after the kill, then beta
        assert later == (["alpha"] if owner == "alpha" else ["beta", "alpha", "beta"]), (s, later)
    print(f"\nfailover (SIGKILL to the survivor's first model): {sorted(round(x, 2) for x in resumed.values())} s")


def _as_user(user: str, password: str, ep: str) -> ZenohSettings:
    auth = json.dumps({"user": user, "password": password})
    return ZenohSettings(connect=(ep,), extra=(("transport/auth/usrpwd", auth),))


def test_the_shipped_router_acl_lets_daemons_share_and_nobody_else_forge_a_member_claim_or_state() -> None:
    """examples/zenoh/router.json5: the sharing keys are the daemons' alone (a forged claim would silence a stream)."""
    root = Path(__file__).resolve().parents[1]
    creds = dict(line.split(":", 1) for line in (root / "examples/zenoh/credentials.txt").read_text().split())
    ep = endpoint()
    conf = root / "examples/zenoh/router.json5"
    router = subprocess.Popen([*STREAMID, "router", "--zenoh-config", str(conf), "--listen", ep], cwd=root,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        seen: list[tuple[str, bool]] = []
        states: list[bytes] = []
        with Bus(_as_user("daemon", creds["daemon"], ep)) as watcher:
            watcher.liveliness_subscribe("streamid/@daemons/*/*", lambda k, a: seen.append((k, a)))
            watcher.liveliness_subscribe("streamid/@claims/*/*/*", lambda k, a: seen.append((k, a)))
            watcher.subscribe("streamid/@state/*", lambda _k, p: states.append(p))
            with Bus(_as_user("sensor", creds["sensor"], ep)) as forger:
                forger.liveliness_token("streamid/@daemons/forged/1")
                forger.liveliness_token("streamid/@claims/dev/forged/1")
                for _ in range(20):
                    forger.put("streamid/@state/dev", b"{}")
                    time.sleep(0.05)
                with Bus(_as_user("daemon", creds["daemon"], ep)) as daemon:
                    daemon.liveliness_token("streamid/@daemons/real/1")
                    daemon.liveliness_token("streamid/@claims/dev/real/1")
                    assert _wait(lambda: len(seen) >= 2, 10)
                    for _ in range(20):
                        daemon.put("streamid/@state/dev", b"{}")
                        if states:
                            break
                        time.sleep(0.05)
                    time.sleep(0.5)
        assert sorted(k for k, alive in seen if alive) == ["streamid/@claims/dev/real/1", "streamid/@daemons/real/1"]
        assert 1 <= len(states) <= 20  # only the daemon's puts arrived (the control proves the path works)
    finally:
        router.terminate()
        router.wait(10)
