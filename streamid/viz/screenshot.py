"""Screenshots of an ``.rrd`` by the real Rerun viewer, headless (no ``rerun`` import here).

:func:`render` starts the viewer binary that ships with rerun-sdk, drives it
through its control API (a client handed in by :func:`streamid.viz.rerun_view.screenshot`)
and writes the picture once the recording is loaded and drawn.  Rendering
from standard input (``rerun --screenshot-to``) takes the shot after a few
frames, before a daemon's thousands of small chunks are all loaded: that gave
empty panels and a time cursor in the middle of the recording.
"""

from __future__ import annotations

import hashlib
import os
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from streamid.errors import ConfigError

__all__ = ["render", "rerun_cli"]


def rerun_cli() -> str:
    """Path of the ``rerun`` command that ships with rerun-sdk (beside the interpreter in a venv, else on PATH)."""
    import shutil
    import sys

    beside = Path(sys.executable).parent / "rerun"
    if beside.exists():
        return str(beside)
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("the `rerun` command of rerun-sdk was not found beside Python or on PATH "
                                "(pip install rerun-sdk)")
    return found


def render(
    rrd: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    png: str | os.PathLike[str],
    *,
    connect: Callable[[str], Any],
    window_size: str = "1280x800",
    timeout_s: float = 90.0,
    settle_s: float = 4.0,
) -> Path:
    """Render ``rrd`` (one .rrd, or several shown together) with the real Rerun viewer, headless, into ``png``.

    Returns the path of the PNG.

    Starts ``rerun --headless`` (the viewer of rerun-sdk, bound to 127.0.0.1 on a
    free port), opens the recording through the viewer's control API, waits until
    the recording is loaded, then takes screenshots until the picture stops
    changing (at least ``settle_s`` after the start, when the viewer's start-up
    notifications are gone) and writes the last one.  The blueprint in the file
    puts the time cursor at the end of the recording and shows the first tab.
    Without a GPU the viewer needs a Vulkan software rasteriser: on
    Debian/Ubuntu ``apt-get install mesa-vulkan-drivers``.

    ``connect(url)`` returns a client of the viewer's control API
    (:meth:`rerun.experimental.ViewerClient.connect`: ``open``, ``get_state``,
    ``take_screenshot``); :func:`streamid.viz.rerun_view.screenshot` passes it, so that this
    module does not import rerun.

    Raises
    ------
    FileNotFoundError
        If a file of ``rrd`` or the ``rerun`` command does not exist.
    ConfigError
        If ``window_size`` is not ``WIDTHxHEIGHT``.
    RuntimeError
        If the viewer cannot start, load the recording or render (the message says why and what to install).
    """
    srcs = [Path(f).resolve() for f in ([rrd] if isinstance(rrd, (str, os.PathLike)) else rrd)]
    if not srcs:
        raise FileNotFoundError("no .rrd file to render: give at least one")
    for src in srcs:
        if not src.is_file():
            raise FileNotFoundError(f"no .rrd file to render at {str(src)!r}")
    name = srcs[0].name if len(srcs) == 1 else f"{srcs[0].name} and {len(srcs) - 1} more"
    out = Path(png)
    if not (isinstance(window_size, str) and len(window_size.split("x")) == 2
            and all(p.isdigit() and int(p) > 0 for p in window_size.split("x"))):
        raise ConfigError(f"window_size must be WIDTHxHEIGHT in points, like '1280x800'; got {window_size!r}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sk:
        sk.bind(("127.0.0.1", 0))
        port = int(sk.getsockname()[1])
    deadline = time.monotonic() + timeout_s
    t0 = time.monotonic()
    with tempfile.TemporaryFile() as said:
        proc = subprocess.Popen(
            [rerun_cli(), "--headless", "--bind", "127.0.0.1", "--port", str(port), "--window-size", window_size,
             "--hide-welcome-screen"],
            stdout=said, stderr=subprocess.STDOUT, start_new_session=True,
        )

        def fail(why: str) -> RuntimeError:
            said.seek(0)
            tail = " | ".join(said.read().decode(errors="replace").strip().splitlines()[-4:])
            return RuntimeError(
                f"the Rerun viewer could not render {name}: {why}. Without a GPU it needs a Vulkan software "
                f"rasteriser (Debian/Ubuntu: apt-get install mesa-vulkan-drivers). Viewer said: {tail or '(nothing)'}"
            )

        try:
            while True:
                if proc.poll() is not None:
                    raise fail(f"it exited at start with code {proc.returncode}")
                if time.monotonic() > deadline:
                    raise fail(f"it did not listen on 127.0.0.1:{port} within {timeout_s:.0f} s")
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    time.sleep(0.05)
            try:
                viewer = connect(f"rerun+http://127.0.0.1:{port}/proxy")
                viewer.open([str(src) for src in srcs])
                while viewer.get_state().loading:
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise fail(f"loading the recording did not finish within {timeout_s:.0f} s")
                    time.sleep(0.1)
                last, same = b"", 0
                while True:  # until the picture is stable: lazily loaded chunks drawn, notifications gone
                    img = viewer.take_screenshot()
                    digest = hashlib.sha256(img).digest()
                    same = same + 1 if digest == last else 0
                    last = digest
                    if same >= 2 and time.monotonic() - t0 >= settle_s:
                        break
                    if time.monotonic() > deadline:
                        raise fail(f"the picture did not settle within {timeout_s:.0f} s")
                    time.sleep(0.3)
            except RuntimeError:
                raise
            except Exception as exc:  # noqa: BLE001 - the viewer's control API raises plain exceptions
                if proc.poll() is not None:
                    raise fail(f"it exited with code {proc.returncode}") from exc
                raise fail(f"{type(exc).__name__}: {exc}") from exc
        finally:
            try:
                os.killpg(proc.pid, signal.SIGTERM)  # the viewer we started, in its own session
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
    if not img.startswith(b"\x89PNG"):
        raise RuntimeError(f"the Rerun viewer returned no PNG picture for {name} ({len(img)} bytes)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    tmp.write_bytes(img)
    os.replace(tmp, out)
    return out
