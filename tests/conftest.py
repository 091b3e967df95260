"""Shared test fixtures: free loopback ports and Zenoh settings for real sessions.

Every Zenoh session in the tests uses explicit ``tcp/127.0.0.1:PORT`` endpoints
with multicast scouting off (the ZenohSettings default), so tests never touch
anything but loopback and never find each other by accident.

Helpers importable from tests (``from conftest import free_tcp_port``):
``free_tcp_port()``, ``endpoint()``, ``rerun_grpc_server(port)``, ``STREAMID`` (argv prefix running the CLI
with the venv's interpreter), ``rerun_check(path)`` (``rerun mcap check``).

System packages (not pip-installable) that some tests need are detected here, in
one place: a test marked ``@pytest.mark.needs("vulkan")`` (or calling
``require("vulkan")``, e.g. in a fixture) is skipped with the Debian package to
install when the thing is absent. ``SYSTEM_NEEDS`` lists them.
"""

from __future__ import annotations

import functools
import time
import shutil
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any
from pathlib import Path

import pytest

from alone import Holder, is_alone, lock_dir_for_run, run_order, worker_lock_dir
from streamid.transport import Bus, ZenohSettings

_LOCK_DIR = pytest.StashKey["Path | None"]()
_HOLDER = pytest.StashKey["Holder"]()

DATA_DIR = Path(__file__).parent / "data"
#: argv prefix that runs the ``streamid`` CLI in a subprocess.
STREAMID = [sys.executable, "-m", "streamid"]


#: the ``rerun`` CLI shipped with rerun-sdk (beside the interpreter in a venv).
RERUN = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")


def rerun_check(path: Path) -> subprocess.CompletedProcess[str]:
    """Run ``rerun mcap check PATH`` (the caller asserts on return code and output)."""
    return subprocess.run([RERUN, "mcap", "check", str(path)], capture_output=True, text=True, timeout=60)


#: Asks the Vulkan loader for the physical devices (a subprocess: a broken driver cannot take pytest down).
_VULKAN_PROBE = r"""
import ctypes, sys
try:
    vk = ctypes.CDLL("libvulkan.so.1")
except OSError:
    sys.exit("no Vulkan loader (libvulkan.so.1)")
class CreateInfo(ctypes.Structure):  # VkInstanceCreateInfo
    _fields_ = [("sType", ctypes.c_int32), ("pNext", ctypes.c_void_p), ("flags", ctypes.c_uint32),
                ("pApplicationInfo", ctypes.c_void_p), ("enabledLayerCount", ctypes.c_uint32),
                ("ppEnabledLayerNames", ctypes.c_void_p), ("enabledExtensionCount", ctypes.c_uint32),
                ("ppEnabledExtensionNames", ctypes.c_void_p)]
info = CreateInfo(sType=1)  # VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO
instance = ctypes.c_void_p()
res = vk.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance))
if res != 0:
    sys.exit(f"vkCreateInstance returned {res} (no Vulkan driver, ICD)")
count = ctypes.c_uint32(0)
res = vk.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None)
vk.vkDestroyInstance(instance, None)
if res != 0 or count.value == 0:
    sys.exit(f"no Vulkan device (vkEnumeratePhysicalDevices returned {res}, {count.value} devices)")
"""


@functools.cache
def vulkan_renderer() -> str | None:
    """None when Vulkan can render here (a loader, a driver and a device), else why not.

    The real Rerun viewer (wgpu) renders through Vulkan; without a GPU it needs a
    software rasteriser (lavapipe, Debian package ``mesa-vulkan-drivers``). Probed
    once per session, by asking the Vulkan loader for its physical devices.
    """
    try:
        res = subprocess.run([sys.executable, "-c", _VULKAN_PROBE], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return "the Vulkan probe did not finish within 60 s"
    return None if res.returncode == 0 else (res.stderr.strip().splitlines() or ["the Vulkan probe failed"])[-1]


def _command(name: str) -> Callable[[], str | None]:
    return lambda: None if shutil.which(name) else f"no `{name}` command on PATH"


@functools.cache
def netns_unavailable() -> str | None:
    """None when tests can run hosts in network namespaces (tests/hosts.py), else why not (probed once)."""
    from hosts import netns_unavailable as probe  # creates and deletes a probe namespace

    return probe()


#: What tests may need beyond pip: name -> (probe returning None when present or why not, what it is and its
#: Debian package). Every other tool the tests run comes with a pip package (``rerun`` with rerun-sdk).
SYSTEM_NEEDS: dict[str, tuple[Callable[[], str | None], str]] = {
    "vulkan": (vulkan_renderer, "a Vulkan renderer (Debian package mesa-vulkan-drivers)"),
    "openssl": (_command("openssl"), "the openssl command (Debian package openssl)"),
    "netns": (netns_unavailable, "network namespaces: root and the ip command (Debian package iproute2)"),
}


def require(what: str) -> None:
    """Skip the calling test (or fixture) when ``what`` (a key of ``SYSTEM_NEEDS``) is absent, naming its package."""
    probe, needs = SYSTEM_NEEDS[what]
    why = probe()
    if why is not None:
        pytest.skip(f"needs {needs}: {why}")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", f"needs(*what): skip unless these system packages are present (one of {', '.join(SYSTEM_NEEDS)})"
    )
    config.addinivalue_line("markers", "alone: run with no other test beside it when the suite runs in several "
                            "processes (tests/alone.py)")
    config.stash[_LOCK_DIR] = lock_dir_for_run(config)  # before the workers start: they inherit its name


def pytest_runtest_setup(item: pytest.Item) -> None:
    for mark in item.iter_markers("needs"):
        for what in mark.args:
            require(what)


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rerun_grpc_server(port: int, wait_s: float = 20.0) -> subprocess.Popen[bytes]:
    """A real ``rerun --serve-grpc`` on 127.0.0.1:``port``, returned once the port accepts (or ``wait_s`` passed).

    The caller ends it (``terminate``/``kill``).  The binary is the one shipped with rerun-sdk.
    """
    binary = str(Path(__import__("rerun_cli").__file__).parent / "rerun")
    server = subprocess.Popen([binary, "--serve-grpc", "--port", str(port), "--bind", "127.0.0.1"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and server.poll() is None:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            break
        except OSError:
            time.sleep(0.1)
    return server


def wait_until(cond: Callable[[], object], timeout_s: float, poll_s: float = 0.05) -> bool:
    """Poll ``cond`` until it is truthy or ``timeout_s`` has passed; whether it became so (asked once more at the
    deadline). A bound on a wait, not a figure: what a test asserts is the condition."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(poll_s)
    return bool(cond())


def read_until(pipe: Any, text: str, max_lines: int = 20, timeout_s: float = 30.0) -> list[str]:
    """Lines read from a process's text ``pipe`` until one holds ``text``, the pipe ends or ``max_lines`` were read
    (in a thread, so that a silent process cannot hang the test past ``timeout_s``); the lines read."""
    lines: list[str] = []

    def read() -> None:
        for _ in range(max_lines):
            lines.append(pipe.readline() if pipe is not None else "")
            if text in lines[-1] or not lines[-1]:
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=timeout_s)
    return lines


def stop_process(proc: subprocess.Popen[Any], wait_s: float = 30.0) -> None:
    """SIGTERM a process this test started, wait ``wait_s`` for it, then SIGKILL it."""
    proc.terminate()
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)


def start_daemon(tmp_path: Path, ep: str, config: str, **popen: Any) -> subprocess.Popen[str]:
    """``streamid daemon --listen ep --config <tmp_path>/d.toml --no-rerun`` with ``config`` as that file (stdout
    discarded and stderr piped unless ``popen`` says otherwise); stop it with :func:`stop_process`."""
    (tmp_path / "d.toml").write_text(config)
    kw: dict[str, Any] = {"stdout": subprocess.DEVNULL, "stderr": subprocess.PIPE, "text": True, **popen}
    return subprocess.Popen([*STREAMID, "daemon", "--listen", ep, "--config", str(tmp_path / "d.toml"), "--no-rerun"],
                            **kw)


@functools.lru_cache(maxsize=4)
def damper_trace(seconds: float, seed: int) -> tuple[Any, Any]:
    """(u, y) of the simulated MR damper, ``seconds`` at 200 Hz from ``seed``, simulated once per test process
    (read-only arrays): tests/test_reliability_bad_input.py and test_reliability_faults.py cut their streams from
    the same 100 s trace (~3 s to simulate, in modules that run alone)."""
    from streamid.sim import get_device

    _, u, y = get_device("mr_damper").simulate_seconds(seconds, seed=seed)
    u.setflags(write=False)
    y.setflags(write=False)
    return u, y


def endpoint(port: int | None = None) -> str:
    """``tcp/127.0.0.1:PORT`` (a fresh free port if none given)."""
    return f"tcp/127.0.0.1:{port if port is not None else free_tcp_port()}"


@pytest.fixture
def zenoh_endpoint() -> str:
    """A fresh ``tcp/127.0.0.1:PORT`` endpoint."""
    return endpoint()


@pytest.fixture
def zenoh_listen(zenoh_endpoint: str) -> ZenohSettings:
    """Settings of a peer listening on :func:`zenoh_endpoint` (multicast off)."""
    return ZenohSettings(listen=(zenoh_endpoint,))


@pytest.fixture
def zenoh_connect(zenoh_endpoint: str) -> ZenohSettings:
    """Settings of a peer connecting to :func:`zenoh_endpoint` (multicast off)."""
    return ZenohSettings(connect=(zenoh_endpoint,))


@pytest.fixture
def bus_pair(zenoh_listen: ZenohSettings, zenoh_connect: ZenohSettings) -> Iterator[tuple[Bus, Bus]]:
    """Two open, connected sessions ``(listener, connector)`` on loopback."""
    a = Bus(zenoh_listen)
    try:
        b = Bus(zenoh_connect)
    except BaseException:
        a.close()
        raise
    try:
        yield a, b
    finally:
        b.close()
        a.close()


# --------------------------------------------------------------------------- tests that run alone (tests/alone.py)
def pytest_unconfigure(config: pytest.Config) -> None:
    path = config.stash.get(_LOCK_DIR, None)
    if path is not None:
        shutil.rmtree(path, ignore_errors=True)


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """The modules that run alone first (tests/alone.py, ``run_order``), then the others; each module's tests in
    their order. A simulation of the suite on its measured durations: 767 s -> 744 s on 2 cores."""
    items.sort(key=run_order)  # stable: the order within each group kept


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    path = worker_lock_dir(item.config)
    if path is None:
        yield
        return
    holder = item.config.stash.get(_HOLDER, None)
    if holder is None:
        holder = item.config.stash[_HOLDER] = Holder(path)
    alone = is_alone(item)
    holder.before(alone)
    try:
        yield
    finally:
        holder.after(alone, nextitem is not None and is_alone(nextitem))
