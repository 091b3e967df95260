"""Reading a file someone else may have made: only a regular file, only up to a bound (no device, FIFO or endless file)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["read_regular_file"]


def read_regular_file(path: str | Path, max_bytes: int, *, head: bool = False) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``max_bytes`` (else ``ValueError`` saying why).

    ``head``: a larger regular file gives its first ``max_bytes`` instead of the error.

    Opened without blocking (a FIFO does not hang the reader) and checked on the open descriptor
    (what is read is what was checked); at most ``max_bytes`` are ever read.

    Raises
    ------
    FileNotFoundError
        If there is no such file.
    OSError
        If it cannot be opened or read.
    ValueError
        If it is not a regular file, or larger than ``max_bytes``.
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{path} is not a regular file (mode {stat.filemode(st.st_mode)}); only regular files are read")
        if st.st_size > max_bytes and not head:
            raise ValueError(f"{path} holds {st.st_size} bytes, more than the {max_bytes} read at most")
        with os.fdopen(os.dup(fd), "rb") as fh:
            raw = fh.read(max_bytes + 1)
        if len(raw) > max_bytes:
            if head:
                return raw[:max_bytes]
            raise ValueError(f"{path} holds more than the {max_bytes} bytes read at most")
        return raw
    finally:
        os.close(fd)
