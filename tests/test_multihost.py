"""Several machines, for real: the router recipe end to end, with separate processes.

``streamid router``, two ``streamid daemon`` (each serving its own stream, its own ``--state-dir``), two
publishers (``streamid replay``) and ``streamid watch --json``, every one of them connected ONLY to the
router (nobody but the router has ``--listen``), all in their default Zenoh mode, the daemons and the
watcher started before the router (they wait for it).  The same scenario runs

- on loopback (every host 127.0.0.1, a fresh port), and
- across network namespaces (``tests/hosts.py``): the router in one namespace, each daemon, each publisher
  and the watcher in its own, joined by veth pairs on a bridge (addresses 10.231.0.0/24 of the test's own
  namespaces only).  Skipped, naming what is missing, without root or ``iproute2``.

Checked: the watcher gets models of both streams; every model of a stream comes from the daemon serving
it (``origin.daemon`` in the documents vs. the id the daemon prints at start); the publishers had a
subscriber (``--require-subscriber``); the router listens on its own address only, nobody else listens
anywhere; every process stops cleanly on Ctrl-C.  Figure printed: time from the publishers' start to
the first model of each stream at the watcher (``pytest -s -n 0``: in one process, so that the prints reach the terminal).
"""

from __future__ import annotations

import json
import re
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from conftest import STREAMID, free_tcp_port, require
from hosts import Network, Proc, netns_network, open_network, wait_listening

#: stream -> the publisher's argv after ``streamid`` (small bundled logs, 200 Hz, played at full speed twice)
PUBLISHERS = {
    "mr_damper": ["replay", "mr_damper", "--max-speed", "--loop", "2", "--require-subscriber"],
    "piezo": ["replay", "piezo_p885", "--stream", "piezo", "--max-speed", "--loop", "2", "--require-subscriber"],
}
#: Upper bound of every wait for a process to be up (a Zenoh session opened, a subscriber seen).
UP_S = 30.0
#: Upper bound of the wait for the first model of every stream at the watcher, after the publishers start.
MODELS_S = 60.0


def _models(watch: Proc) -> list[dict[str, Any]]:
    docs = []
    for line in watch.text().splitlines():
        if line.startswith("{"):
            try:
                doc = json.loads(line)
            except json.JSONDecodeError:  # a line still being written
                continue
            if doc.get("format") == "streamid.model-update/1":  # --json prints status events too
                docs.append(doc)
    return docs


def run_recipe(net: Network, port: int, tmp_path: Path) -> dict[str, float]:
    """Router, two daemons, a watcher, two publishers on the hosts of ``net``; checks and returns the seconds
    from the publishers' start to each stream's first model at the watcher."""
    assert len(net.hosts) >= 5
    ep = net.router_endpoint(port)
    # the daemons and the watcher first: nothing answers yet, they say so and wait for the router
    daemons: dict[str, Proc] = {}
    for host, stream in zip(net.hosts[:2], PUBLISHERS):
        argv = [*STREAMID, "daemon", "--connect", ep, "--stream", stream, "--state-dir", str(tmp_path / f"state-{stream}"),
                "--no-rerun"]
        assert "--listen" not in argv  # connected only to the router: a client by default
        daemons[stream] = host.run(argv, tmp_path / f"daemon-{stream}.log", cwd=tmp_path)
    watch = net.hosts[2].run([*STREAMID, "watch", "--connect", ep, "--json"], tmp_path / "watch.log")
    for proc in (*daemons.values(), watch):
        assert proc.wait_for(r"nothing (answers|reachable) at .*yet", UP_S) is not None, proc.text()

    router = net.router.run([*STREAMID, "router", "--listen", ep], tmp_path / "router.log")
    assert wait_listening(router, UP_S) == [ep], router.text()
    ids = {}
    for stream, d in daemons.items():
        m = d.wait_for(r"serving on (\S+) as daemon (\w+)", UP_S)
        assert m is not None, d.text()
        assert m.group(1).rstrip(",;") == ep
        ids[stream] = m.group(2)
    assert len(set(ids.values())) == 2, ids
    assert watch.wait_for(r"waiting for models", UP_S) is not None, watch.text()

    t0_ns = time.time_ns()
    pubs = {stream: host.run([*STREAMID, *argv, "--connect", ep], tmp_path / f"publisher-{stream}.log")
            for host, (stream, argv) in zip(net.hosts[3:5], PUBLISHERS.items())}
    first: dict[str, int] = {}
    deadline = time.monotonic() + MODELS_S
    while len(first) < len(PUBLISHERS) and time.monotonic() < deadline:
        for doc in _models(watch):
            first.setdefault(doc["stream"], int(doc["published_unix_ns"]))
        time.sleep(0.1)

    # while everything runs: who listens where
    listening = {h.name: h.listening(None if net.kind == "netns" else [p.pid for p in h.procs]) for h in net.all}
    for name, pub in pubs.items():
        assert pub.popen.wait(timeout=MODELS_S) == 0, pub.text()
        assert "no subscriber" not in pub.text(), pub.text()
    codes = {p.name: p.stop() for p in (watch, *daemons.values(), router)}

    assert set(first) == set(PUBLISHERS), (f"models of {sorted(first)} only", watch.text()[-3000:],
                                           {s: d.text()[-2000:] for s, d in daemons.items()})
    docs = _models(watch)
    for stream in PUBLISHERS:
        origins = {d["origin"]["daemon"] for d in docs if d["stream"] == stream}
        assert origins == {ids[stream]}, (stream, origins, ids)  # served by its daemon, and only by it
    assert codes == {p.name: 0 for p in (watch, *daemons.values(), router)}, codes
    assert [f"{ls.proto}/{ls.local}" for ls in listening[net.router.name]] == [ep], listening
    assert all(not listening[h.name] for h in net.hosts), listening  # the daemons, watcher, publishers: nowhere
    return {s: (first[s] - t0_ns) / 1e9 for s in PUBLISHERS}


@pytest.fixture(params=["loopback", pytest.param("netns", marks=pytest.mark.alone)])  # fixed namespaces
def network(request: pytest.FixtureRequest) -> Iterator[Network]:
    if request.param == "netns":
        require("netns")
    with open_network(request.param, 5) as net:
        yield net


def test_router_recipe_two_daemons_two_publishers_a_watcher(network: Network, tmp_path: Path) -> None:
    port = 7447 if network.kind == "netns" else free_tcp_port()  # a namespace has its own ports
    seconds = run_recipe(network, port, tmp_path)
    print(f"\n{network.kind}: publishers started -> first model at the watcher: "
          + ", ".join(f"{s} {v:.2f} s" for s, v in seconds.items()))
    assert all(0 < v < MODELS_S for v in seconds.values()), seconds


@pytest.mark.alone  # namespaces of fixed names
def test_netns_hosts_reach_the_router_only_and_leave_nothing_behind(tmp_path: Path) -> None:
    """The harness itself: hosts reach the router's address, not the machine's; teardown removes every namespace
    and kills what still ran in it; a namespace left by a run that was killed (its pid gone) is removed."""
    require("netns")
    stale = "sid999999999-abcdefr"  # pid above any pid_max: its creator is gone
    subprocess.run(["ip", "netns", "add", stale], check=True, capture_output=True, timeout=10)
    with netns_network(2) as net:
        assert stale not in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=10).stdout
        names = [h.netns for h in net.all]
        probe = ("import socket,sys\ns=socket.socket();s.settimeout(2)\n"
                 "try:\n s.connect((sys.argv[1],int(sys.argv[2])));print('connected')\n"
                 "except OSError as e:\n print('refused' if isinstance(e,ConnectionRefusedError) else 'unreachable')")
        srv = net.router.run(["python3", "-c", "import socket,time\ns=socket.socket();s.bind(('0.0.0.0',9));"
                              "s.listen();print('up',flush=True);time.sleep(60)"], tmp_path / "srv.log")
        assert srv.wait_for("up", UP_S) is not None, srv.text()
        assert net.hosts[0].exec(["python3", "-c", probe, net.router.address, "9"]).stdout.strip() == "connected"
        assert net.hosts[0].exec(["python3", "-c", probe, net.hosts[1].address, "9"]).stdout.strip() == "refused"
        gw = subprocess.run(["ip", "-4", "route", "show", "default"], capture_output=True, text=True, timeout=10)
        outside = re.search(r"via (\S+)", gw.stdout)
        if outside:  # the machine's own gateway is not reachable from a test host
            assert net.hosts[0].exec(["python3", "-c", probe, outside.group(1), "53"]).stdout.strip() == "unreachable"
        leftover = net.hosts[1].run(["sleep", "120"], tmp_path / "sleep.log")
    assert srv.popen.returncode is not None and leftover.popen.returncode is not None
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=10).stdout
    assert not any(n in listed for n in names if n), listed
