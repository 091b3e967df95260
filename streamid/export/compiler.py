"""The one compile step of an export: C sources into a shared library, with the system's C compiler.

The compiler is ``$CC`` when set, else ``cc``, else ``gcc`` (looked up on ``PATH``). Without one the error is
one line naming what to install (and ``--sources-only``, which needs none).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

from streamid.errors import ConfigError

__all__ = ["INSTALL_HINT", "compile_shared", "find_compiler"]

INSTALL_HINT = ("no C compiler found ($CC, cc or gcc on PATH): install one (Debian/Ubuntu: apt-get install gcc; "
                "Fedora: dnf install gcc; macOS: xcode-select --install), or pass --sources-only to write the FMU's "
                "sources without a binary")

#: Flags of every compile: the code is C99 and must build warning-free.
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra")


def find_compiler() -> str:
    """The C compiler's path, or a :class:`ConfigError` saying what to install."""
    for name in (os.environ.get("CC", ""), "cc", "gcc"):
        if name:
            found = shutil.which(name)
            if found:
                return found
    raise ConfigError(INSTALL_HINT)


def compile_shared(sources: Sequence[Path], include: Path, out: Path, *, timeout_s: float = 120.0) -> Path:
    """Compile ``sources`` (with ``include`` on the include path) into the shared library ``out`` (linked to libm).

    Raises
    ------
    ConfigError
        No compiler (:data:`INSTALL_HINT`), or the compiler failed (its last lines of output are given).
    """
    cc = find_compiler()
    cmd = [cc, *CFLAGS, "-shared", f"-I{include}", "-o", str(out), *(str(s) for s in sources), "-lm"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ConfigError(f"the C compiler {cc} could not be run: {exc}") from None
    if done.returncode != 0 or not out.is_file():
        said = " | ".join((done.stderr or done.stdout).strip().splitlines()[-5:])
        raise ConfigError(f"the C compiler {cc} failed (exit {done.returncode}) on the generated code: {said}")
    return out
