"""Several "machines" on one box for tests: network namespaces (``ip netns``) or plain loopback.

A :class:`Network` is a router host and N other hosts, each with an address; every process a test
starts runs on one host (``host.run(argv, log)``), with its stdout and stderr captured to a file, and
is ended when the network is torn down.  Two kinds, one interface, so a scenario runs on either:

- :func:`netns_network` (root and ``iproute2`` needed; :func:`netns_unavailable` says why not):
  one network namespace per host, named ``sid<pid>-<token>r`` (the router) and ``sid<pid>-<token>h1`` ...
  (``pid`` the creating process, ``token`` random, so concurrent runs never collide; a later run deletes the
  namespaces of a creator that is gone, e.g. a SIGKILLed pytest).  The router's namespace holds a
  bridge ``br0`` with ``<subnet>.1/24``; host ``i`` is joined to it by a veth pair and has
  ``<subnet>.<10 + i>/24`` on its ``eth0``.  The veth ends are created directly inside the
  namespaces: the machine's own namespace never gets an interface, an address or a route, so
  nothing here can reach (or be reached from) anything but the other test hosts.  Nothing is
  forwarded between the bridge and anything else.
- :func:`loopback_network`: every host is ``127.0.0.1`` in the machine's own namespace.

Teardown (always, also when the test fails): every process started on a host gets SIGINT, then
SIGKILL after a bound; in a namespace, any process still in it (``ip netns pids``: only descendants
of what the test started can be there) is killed by its pid; then the namespaces are deleted, which
deletes the veth pairs and the bridge with them.

    with netns_network(3) as net:                     # or loopback_network(3)
        ep = net.router_endpoint(7447)               # a namespace has its own ports; on loopback pick a free one
        router = net.router.run([*STREAMID, "router", "--listen", ep], tmp_path / "router.log")
        assert wait_listening(router, 20.0) == [ep]   # what it listens on, seen from its host
        daemon = net.hosts[0].run([*STREAMID, "daemon", "--connect", ep], tmp_path / "d1.log")
        m = daemon.wait_for(r"as daemon (\\w+)", 30.0)  # its output so far: daemon.text()
        daemon.kill()                                 # SIGKILL: a crash (failover); .stop() is Ctrl-C
"""

from __future__ import annotations

import ipaddress
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

#: The addresses of test namespaces: ``<subnet>.1`` the router, ``<subnet>.11`` ... the hosts.
DEFAULT_SUBNET = "10.231.0"
#: Upper bound of one ``ip`` command.
IP_TIMEOUT_S = 10.0


class NetnsError(RuntimeError):
    """An ``ip`` command that builds or inspects the test network failed (its argv and output in the message)."""


def _ip(*args: str, timeout_s: float = IP_TIMEOUT_S) -> str:
    argv = ["ip", *args]
    try:
        p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise NetnsError(f"{' '.join(argv)}: {exc}") from exc
    if p.returncode != 0:
        raise NetnsError(f"{' '.join(argv)} exited {p.returncode}: {(p.stderr or p.stdout).strip()}")
    return p.stdout


def netns_unavailable() -> str | None:
    """None when this process can build namespaced hosts (namespaces + veth + bridge), else why not."""
    if shutil.which("ip") is None:
        return "no `ip` command on PATH"
    if os.geteuid() != 0:
        return f"not root (uid {os.geteuid()}): creating network namespaces needs root"
    probe = f"sidprobe{secrets.token_hex(3)}"
    try:
        _ip("netns", "add", probe)
    except NetnsError as exc:
        return f"cannot create a network namespace: {exc}"
    try:
        _ip("-n", probe, "link", "add", "br0", "type", "bridge")
        _ip("link", "add", "name", "a", "netns", probe, "type", "veth", "peer", "name", "b", "netns", probe)
        return None
    except NetnsError as exc:
        return f"cannot create a bridge and a veth pair in a network namespace: {exc}"
    finally:
        try:
            _ip("netns", "del", probe)
        except NetnsError:
            pass


@dataclass
class Proc:
    """A process started on a host; its stdout and stderr (merged, unbuffered) go to ``log``."""

    name: str
    popen: subprocess.Popen[bytes]
    log: Path
    host: "Host"
    #: wall clock when it was started (compare with the ``*_unix_ns`` of documents)
    started_unix_ns: int
    _file: IO[bytes] = field(repr=False)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def text(self) -> str:
        """Everything it printed so far."""
        return self.log.read_text(encoding="utf-8", errors="replace") if self.log.exists() else ""

    def wait_for(self, pattern: str, timeout_s: float) -> re.Match[str] | None:
        """The first match of ``pattern`` (multiline) in its output, waiting up to ``timeout_s``; None if the
        time ran out or the process ended without printing it."""
        rx = re.compile(pattern, re.M)
        deadline = time.monotonic() + timeout_s
        for _ in range(int(timeout_s / 0.05) + 2):
            ended = not self.alive()
            m = rx.search(self.text())
            if m is not None or ended or time.monotonic() >= deadline:
                return m
            time.sleep(0.05)
        return None

    def stop(self, timeout_s: float = 15.0) -> int:
        """SIGINT (Ctrl-C), then SIGKILL after ``timeout_s``; the exit code (negative: killed by that signal)."""
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(timeout=10)
        self._file.close()
        return self.popen.returncode

    def kill(self) -> int:
        """SIGKILL now (a crash); the exit code."""
        if self.popen.poll() is None:
            self.popen.kill()
        self.popen.wait(timeout=10)
        self._file.close()
        return self.popen.returncode


@dataclass(frozen=True)
class Listener:
    """A listening socket seen by ``ss`` on a host: ``proto`` tcp/udp, ``local`` "ADDR:PORT", owner ``pid``."""

    proto: str
    local: str
    pid: int | None


@dataclass(frozen=True)
class Host:
    """One machine: a name, its address, its namespace (None: the machine's own, loopback)."""

    name: str
    address: str
    netns: str | None
    procs: list[Proc] = field(default_factory=list, compare=False, repr=False)

    def command(self, argv: Sequence[str]) -> list[str]:
        """``argv`` as run on this host (``ip netns exec NS ...``: it execs, so the pid is the program's)."""
        return ["ip", "netns", "exec", self.netns, *argv] if self.netns else list(argv)

    def run(self, argv: Sequence[str], log: Path, *, cwd: Path | None = None,
            env: dict[str, str] | None = None, name: str | None = None) -> Proc:
        """Start ``argv`` on this host, output to ``log``; ended at the latest when the network is torn down."""
        log.parent.mkdir(parents=True, exist_ok=True)
        out = open(log, "wb")
        try:
            popen = subprocess.Popen(self.command(argv), stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     cwd=cwd, env=dict(env if env is not None else os.environ, PYTHONUNBUFFERED="1"))
        except BaseException:
            out.close()
            raise
        proc = Proc(name or log.stem, popen, log, self, time.time_ns(), out)
        self.procs.append(proc)
        return proc

    def exec(self, argv: Sequence[str], timeout_s: float = 60.0, *,
             cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` on this host to the end (bounded), output captured."""
        return subprocess.run(self.command(argv), capture_output=True, text=True, timeout=timeout_s, cwd=cwd)

    def listening(self, pids: Iterable[int] | None = None) -> list[Listener]:
        """The TCP sockets in LISTEN state and the bound UDP sockets of this host, read from ``/proc`` (no
        ``ss`` needed): of ``pids`` only if given (needed on loopback, where the host is the whole machine),
        else every socket of the host's namespace (owner: the pid of the namespace holding it, or None)."""
        if pids is None:
            if self.netns is None:
                raise ValueError("listening() on a loopback host needs the pids (the host is the whole machine)")
            owners = [int(x) for x in _ip("netns", "pids", self.netns).split()]
            names = " ".join(f"/proc/self/net/{n}" for n, _, _ in _TABLES)
            shown = self.exec(["sh", "-c", f"for f in {names}; do echo \"## $f\"; cat $f 2>/dev/null; done"],
                              timeout_s=IP_TIMEOUT_S).stdout  # this namespace's tables, also with nobody in it
            texts = {name: part for name, part in re.findall(r"^## /proc/self/net/(\w+)\n(.*?)(?=^## |\Z)", shown,
                                                             re.M | re.S)}
            sockets = _sockets(texts)
        else:
            owners = list(pids)
            sockets = [s for pid in owners for s in _sockets(_tables_of(pid))]
        inode_pid: dict[str, int] = {}
        for pid in owners:
            for inode in _socket_inodes(pid):
                inode_pid.setdefault(inode, pid)
        found: dict[tuple[str, str], Listener] = {}
        for proto, local, inode in sockets:
            if pids is None or inode in inode_pid:
                found.setdefault((proto, local), Listener(proto, local, inode_pid.get(inode)))
        return sorted(found.values(), key=lambda ls: (ls.proto, ls.local))


#: /proc/net tables read for listening sockets: (file, protocol, the state that counts: TCP LISTEN, UDP unconnected)
_TABLES = (("tcp", "tcp", "0A"), ("tcp6", "tcp", "0A"), ("udp", "udp", "07"), ("udp6", "udp", "07"))


def _tables_of(pid: int) -> dict[str, str]:
    texts = {}
    for name, _, _ in _TABLES:
        try:
            texts[name] = Path(f"/proc/{pid}/net/{name}").read_text()
        except OSError:  # ended
            pass
    return texts


def _sockets(texts: dict[str, str]) -> list[tuple[str, str, str]]:
    """(proto, local "ADDR:PORT", inode) of the listening TCP and bound UDP sockets in /proc/net tables."""
    out = []
    for name, proto, state in _TABLES:
        for line in texts.get(name, "").splitlines()[1:]:
            cols = line.split()
            if len(cols) > 9 and cols[3] == state:
                out.append((proto, _hex_address(cols[1]), cols[9]))
    return out


def _socket_inodes(pid: int) -> set[str]:
    inodes: set[str] = set()
    try:
        fds = list(Path(f"/proc/{pid}/fd").iterdir())
    except OSError:  # ended
        return inodes
    for fd in fds:
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    return inodes


def _hex_address(text: str) -> str:
    """``0100007F:1D27`` -> ``127.0.0.1:7463``; IPv6 as ``[addr]:port``."""
    addr, port = text.split(":")
    raw = bytes.fromhex(addr)
    if sys.byteorder == "little":  # /proc prints the address as 32-bit words in host order
        raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    ip = ipaddress.ip_address(raw)
    return f"{ip}:{int(port, 16)}" if ip.version == 4 else f"[{ip}]:{int(port, 16)}"


@dataclass(frozen=True)
class Network:
    """A router host and the other hosts; ``kind`` is "netns" or "loopback"."""

    kind: str
    router: Host
    hosts: tuple[Host, ...]

    @property
    def all(self) -> tuple[Host, ...]:
        return (self.router, *self.hosts)

    def procs(self) -> list[Proc]:
        """Every process started on the hosts of this network."""
        return [p for h in self.all for p in h.procs]

    def router_endpoint(self, port: int, proto: str = "tcp") -> str:
        """``proto/ROUTER_ADDRESS:port``: what the router listens on and everybody else connects to."""
        return f"{proto}/{self.router.address}:{port}"


def wait_listening(proc: Proc, timeout_s: float) -> list[str]:
    """The ``proto/ADDR:PORT`` endpoints ``proc`` listens on, as soon as it listens somewhere (bounded wait;
    [] if it never did or ended)."""
    deadline = time.monotonic() + timeout_s
    for _ in range(int(timeout_s / 0.1) + 2):
        found = [f"{ls.proto}/{ls.local}" for ls in proc.host.listening([proc.pid])]
        if found or not proc.alive() or time.monotonic() >= deadline:
            return found
        time.sleep(0.1)
    return []


def _stop_all(procs: list[Proc]) -> None:
    for p in procs:
        if p.alive():
            p.popen.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 10.0
    for p in procs:
        try:
            p.popen.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.popen.kill()
            p.popen.wait(timeout=10)
        p._file.close()


@contextmanager
def loopback_network(n_hosts: int) -> Iterator[Network]:
    """``n_hosts`` hosts and a router, all ``127.0.0.1`` in this machine's namespace (processes ended on exit)."""
    net = Network("loopback", Host("router", "127.0.0.1", None), tuple(Host(f"h{i}", "127.0.0.1", None)
                                                                       for i in range(1, n_hosts + 1)))
    try:
        yield net
    finally:
        _stop_all(net.procs())


@contextmanager
def netns_network(n_hosts: int, *, subnet: str = DEFAULT_SUBNET) -> Iterator[Network]:
    """A router namespace and ``n_hosts`` host namespaces on one bridge (see the module docstring).

    Raises :class:`NetnsError` when the network cannot be built (call :func:`netns_unavailable` first to
    skip instead); whatever was created is removed on the way out, also on failure.
    """
    if not 1 <= n_hosts <= 200:
        raise ValueError(f"n_hosts must be 1..200; got {n_hosts}")
    if not re.fullmatch(r"10\.\d{1,3}\.\d{1,3}", subnet):
        raise ValueError(f"subnet must be the first three numbers of a 10.x.y.0/24 network, e.g. 10.231.0; got {subnet!r}")
    _remove_stale()
    token = f"{os.getpid()}-{secrets.token_hex(3)}"
    router = Host(f"sid{token}r", f"{subnet}.1", f"sid{token}r")
    hosts = tuple(Host(f"sid{token}h{i}", f"{subnet}.{10 + i}", f"sid{token}h{i}") for i in range(1, n_hosts + 1))
    net = Network("netns", router, hosts)
    made: list[str] = []
    try:
        _ip("netns", "add", router.name)
        made.append(router.name)
        _ip("-n", router.name, "link", "set", "lo", "up")
        _ip("-n", router.name, "link", "add", "br0", "type", "bridge")
        _ip("-n", router.name, "addr", "add", f"{router.address}/24", "dev", "br0")
        _ip("-n", router.name, "link", "set", "br0", "up")
        for i, h in enumerate(hosts, start=1):
            _ip("netns", "add", h.name)
            made.append(h.name)
            _ip("-n", h.name, "link", "set", "lo", "up")
            _ip("link", "add", "name", "eth0", "netns", h.name, "type", "veth", "peer", "name", f"h{i}",
                "netns", router.name)
            _ip("-n", h.name, "addr", "add", f"{h.address}/24", "dev", "eth0")
            _ip("-n", h.name, "link", "set", "eth0", "up")
            _ip("-n", router.name, "link", "set", f"h{i}", "master", "br0")
            _ip("-n", router.name, "link", "set", f"h{i}", "up")
        yield net
    finally:
        try:
            _stop_all(net.procs())
        finally:
            for ns in reversed(made):
                _kill_left_in(ns)
                try:
                    _ip("netns", "del", ns)
                except NetnsError:
                    pass


def open_network(kind: str, n_hosts: int) -> AbstractContextManager[Network]:
    """:func:`netns_network` (``kind`` "netns") or :func:`loopback_network` ("loopback") of ``n_hosts`` hosts."""
    if kind == "netns":
        return netns_network(n_hosts)
    if kind == "loopback":
        return loopback_network(n_hosts)
    raise ValueError(f"kind must be 'netns' or 'loopback'; got {kind!r}")


_NAME = re.compile(r"^sid(\d+)-[0-9a-f]{6}(r|h\d+)$")


def _remove_stale() -> None:
    """Delete the test namespaces (``sid<pid>-<token>...``) of runs whose process is gone (killed before teardown)."""
    try:
        listed = _ip("netns", "list")
    except NetnsError:
        return
    for line in listed.splitlines():
        m = _NAME.match(line.split(" ")[0])
        if m is None or Path(f"/proc/{m.group(1)}").exists():
            continue
        _kill_left_in(m.group(0))
        try:
            _ip("netns", "del", m.group(0))
        except NetnsError:
            pass


def _kill_left_in(ns: str) -> None:
    """SIGKILL, by pid, whatever still runs in the test namespace ``ns`` (only what the test started can)."""
    try:
        pids = [int(x) for x in _ip("netns", "pids", ns).split()]
    except (NetnsError, ValueError):
        return
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + 5.0
    while pids and time.monotonic() < deadline:
        try:
            pids = [int(x) for x in _ip("netns", "pids", ns).split()]
        except (NetnsError, ValueError):
            return
        time.sleep(0.05)
