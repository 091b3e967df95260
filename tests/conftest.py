"""Shared test fixtures: free loopback ports and Zenoh settings for real sessions.

Every Zenoh session in the tests uses explicit ``tcp/127.0.0.1:PORT`` endpoints
with multicast scouting off (the ZenohSettings default), so tests never touch
anything but loopback and never find each other by accident.

Helpers importable from tests (``from conftest import free_tcp_port``):
``free_tcp_port()``, ``endpoint()``, ``STREAMID`` (argv prefix running the CLI
with the venv's interpreter), ``rerun_check(path)`` (``rerun mcap check``).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from streamid.transport import Bus, ZenohSettings

DATA_DIR = Path(__file__).parent / "data"
#: argv prefix that runs the ``streamid`` CLI in a subprocess.
STREAMID = [sys.executable, "-m", "streamid"]


#: the ``rerun`` CLI shipped with rerun-sdk (beside the interpreter in a venv).
RERUN = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")


def rerun_check(path: Path) -> subprocess.CompletedProcess[str]:
    """Run ``rerun mcap check PATH`` (the caller asserts on return code and output)."""
    return subprocess.run([RERUN, "mcap", "check", str(path)], capture_output=True, text=True, timeout=60)


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


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
