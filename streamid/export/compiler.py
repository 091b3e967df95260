"""The one compile step of an export: C sources into a shared library, with the system's C compiler.

The compiler is ``$CC`` when set, else ``cc``, else ``gcc`` (looked up on ``PATH``). Without one the error is
one line naming what to install (and ``--sources-only``, which needs none). It runs in a process group of its
own, killed whole on its time budget or when the caller stops (no orphaned ``cc1``).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from streamid.errors import ConfigError

__all__ = ["INSTALL_HINT", "MAX_COMPILE_ESTIMATE_S", "MAX_COMPILE_REGRESSORS", "compile_budget_s", "compile_shared",
           "find_compiler"]

INSTALL_HINT = ("no C compiler found ($CC, cc or gcc on PATH): install one (Debian/Ubuntu: apt-get install gcc; "
                "Fedora: dnf install gcc; macOS: xcode-select --install), or pass --sources-only to write the FMU's "
                "sources without a binary")

#: Flags of every compile: the code is C99 and must build warning-free.
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra")

#: Regressors of one network (its own and its linear part's, each a line of its C function) above which no binary is
#: compiled: gcc -O2's time and memory grow with their square (measured, docs/security.md: 2000 -> 18 s, 660 MB;
#: 4096 -> 108 s, 2.9 GB). The online long linear part (order <= 512) of a stream of up to 4 inputs stays below.
MAX_COMPILE_REGRESSORS = 2600
#: Estimated compile time (:func:`compile_budget_s`) above which no binary is compiled.
MAX_COMPILE_ESTIMATE_S = 120.0


def compile_budget_s(regressors_per_network: Sequence[int], numbers: int) -> tuple[float, float]:
    """``(estimate, budget)`` in seconds of compiling a model's C code: the estimate from its networks' regressors
    (the square of each: one C function each) and its numbers, measured with gcc 12 -O2 on the project's machines
    (0.4 s + 1e-5 s a number + 6e-6 s a regressor squared); the budget 30 s or 3 x the estimate, the larger."""
    estimate = 0.4 + 1e-5 * numbers + 6e-6 * sum(k * k for k in regressors_per_network)
    return estimate, max(30.0, 3.0 * estimate)


def find_compiler() -> str:
    """The C compiler's path, or a :class:`ConfigError` saying what to install."""
    for name in (os.environ.get("CC", ""), "cc", "gcc"):
        if name:
            found = shutil.which(name)
            if found:
                return found
    raise ConfigError(INSTALL_HINT)


def compile_shared(sources: Sequence[Path], include: Path, out: Path, *, timeout_s: float = 120.0,
                   cancelled: Callable[[], bool] | None = None) -> Path:
    """Compile ``sources`` (with ``include`` on the include path) into the shared library ``out`` (linked to libm).

    The compiler runs in a process group of its own (a new session): on ``timeout_s`` or when ``cancelled()``
    turns true (polled every 0.1 s) the whole group is killed, the driver and ``cc1``/``as``/``ld`` with it, so no
    compiler process outlives the call. Its output goes to a file beside ``out``; the last lines are quoted.

    Raises
    ------
    ConfigError
        No compiler (:data:`INSTALL_HINT`), the compiler failed (its last lines of output are given), it ran over
        ``timeout_s``, or it was cancelled.
    """
    cc = find_compiler()
    cmd = [cc, *CFLAGS, "-shared", f"-I{include}", "-o", str(out), *(str(s) for s in sources), "-lm"]
    log = out.with_name(f".{out.name}.cc.log")
    try:
        with open(log, "wb") as sink:
            proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=sink, stderr=subprocess.STDOUT,
                                    start_new_session=True)
    except OSError as exc:
        raise ConfigError(f"the C compiler {cc} could not be run: {exc}") from None
    end = time.monotonic() + timeout_s
    why = ""
    try:
        while True:
            try:
                proc.wait(timeout=0.1)
                break
            except subprocess.TimeoutExpired:
                if cancelled is not None and cancelled():
                    why = "stopped (the command is ending)"
                elif time.monotonic() >= end:
                    why = f"ran over its budget of {timeout_s:.0f} s"
                if why:
                    break
    finally:
        _kill_group(proc)
    if why:
        raise ConfigError(f"the C compiler {cc} {why}; its process group was killed and nothing was written")
    said = _tail(log)
    if proc.returncode != 0 or not out.is_file():
        raise ConfigError(f"the C compiler {cc} failed (exit {proc.returncode}) on the generated code: {said}")
    return out


def _kill_group(proc: subprocess.Popen[bytes]) -> None:
    """Kill ``proc``'s whole process group (its own session: nothing else is in it) and reap ``proc``."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # also when proc ended: a child it left in its group goes too
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def _tail(log: Path, lines: int = 5, most: int = 4096) -> str:
    """The last ``lines`` lines of the compiler's output (of its last ``most`` bytes), on one line."""
    try:
        with open(log, "rb") as f:
            f.seek(max(0, log.stat().st_size - most))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    return " | ".join(text.strip().splitlines()[-lines:])
