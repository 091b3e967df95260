"""MATLAB ``.mat`` files (v4 to v7.2, :func:`scipy.io.loadmat`), read within stated bounds.

Every numeric 2-D variable is a column (``N x 1`` or ``1 x N``), a matrix ``X`` of ``N x k`` gives columns
``X[0] .. X[k-1]``; anything else is skipped.  Before anything is loaded:

* the file's compressed variables are inflated in a stream (1 MiB at a time, the output discarded) to count what
  they expand to: more than :data:`MAX_MAT_EXPANDED_BYTES` together is refused (a few hundred kB of zlib can
  expand to gigabytes, and a variable's header can lie about its size);
* the variables' shapes and classes are read from their headers (parsed from the start of that stream for
  MATLAB v5 files, whose compressed variables :func:`scipy.io.whosmat` inflates whole; :func:`scipy.io.whosmat`
  for v4): numeric variables of more than :data:`MAX_MAT_ELEMENTS` elements together are refused (each element
  becomes a float64: a ``uint8`` variable grows 8 times), naming the largest;

and only the numeric variables are then loaded, converted to float64 one column at a time.  Each refusal and each
damaged file is one :class:`~streamid.errors.DataError` line naming the file.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError

__all__ = ["MAX_MAT_ELEMENTS", "MAX_MAT_EXPANDED_BYTES", "read_mat_columns", "scan_v5"]

#: Elements of the numeric variables read from one ``.mat`` (2**25: 256 MiB as float64; e.g. 8M samples x 4).
MAX_MAT_ELEMENTS = 32 * 1024 * 1024
#: Bytes the variables of one ``.mat`` may expand to, together (the float64 columns of MAX_MAT_ELEMENTS, and 32 MiB).
MAX_MAT_EXPANDED_BYTES = 8 * MAX_MAT_ELEMENTS + 32 * 1024 * 1024
_CHUNK = 1 << 20
_MI_COMPRESSED = 15
_NUMERIC = frozenset({"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                      "logical"})
_T = TypeVar("_T")


def _scipy(path: Path, call: Callable[[], _T]) -> _T:
    """``call()`` (a scipy reader of ``path``) with every failure of a damaged file as one DataError line."""
    try:
        return call()
    except NotImplementedError:
        raise DataError(f"{path}: MATLAB v7.3 (HDF5) files are not supported; save with -v7 or export CSV") from None
    except (MemoryError, RecursionError):
        raise DataError(f"{path}: not a readable MATLAB .mat file (its headers ask for more memory than there is: "
                        "damaged?)") from None
    except Exception as exc:  # noqa: BLE001 - scipy's reader raises many kinds on a damaged file (IndexError,
        # MatReadError, ValueError, zlib.error ...): each is this file's fault, said in one line
        raise DataError(f"{path}: not a readable MATLAB .mat file: {type(exc).__name__}: {str(exc)[:200]} (a .mat "
                        "of MATLAB v4-v7.2 with numeric variables is read; a cut or damaged file is not)") from None


_CLASSES = {6: "double", 7: "single", 8: "int8", 9: "uint8", 10: "int16", 11: "uint16", 12: "int32", 13: "uint32",
            14: "int64", 15: "uint64", 1: "cell", 2: "struct", 3: "object", 4: "char", 5: "sparse"}
#: Bytes of a variable's start in which its header (flags, dimensions, name) must be.
_HEADER_BYTES = 4096


def _inflated(fh: Any, n_bytes: int, budget: int) -> tuple[int, bytes]:
    """(bytes the zlib stream of the next ``n_bytes`` of ``fh`` expands to, its first :data:`_HEADER_BYTES`);
    counting stops past ``budget``; the rest of the output is discarded as it comes."""
    d = zlib.decompressobj()
    out = 0
    head = b""
    left = n_bytes
    while left > 0 and not d.eof:
        chunk = fh.read(min(_CHUNK, left))
        if not chunk:
            break
        left -= len(chunk)
        buf = chunk
        while buf and not d.eof:
            piece = d.decompress(buf, _CHUNK)
            if len(head) < _HEADER_BYTES:
                head += piece[: _HEADER_BYTES - len(head)]
            out += len(piece)
            buf = d.unconsumed_tail
            if out > budget:
                return out, head
    return out, head


def _element(buf: bytes, pos: int, order: str) -> tuple[int, bytes, int]:
    """(type, data, next position) of the data element at ``pos`` (regular or small format)."""
    word, n = struct.unpack_from(order + "II", buf, pos)
    if word >> 16:  # small data element: type and size in the first word, data in the second
        return word & 0xFFFF, buf[pos + 4: pos + 4 + (word >> 16)], pos + 8
    if pos + 8 + n > len(buf):
        raise ValueError("cut")
    return word, buf[pos + 8: pos + 8 + n], pos + 8 + n + (-n) % 8


def _header(buf: bytes, order: str) -> tuple[str, tuple[int, ...], str] | None:
    """(name, shape, class) of the miMATRIX element at the start of ``buf`` (None: not one, or not readable here)."""
    try:
        kind, _ = struct.unpack_from(order + "II", buf, 0)
        if kind != 14:
            return None
        _, flags, pos = _element(buf, 8, order)
        _, dims, pos = _element(buf, pos, order)
        _, name, pos = _element(buf, pos, order)
        word = struct.unpack_from(order + "I", flags, 0)[0]
        shape = struct.unpack(f"{order}{len(dims) // 4}i", dims[: len(dims) // 4 * 4])
    except (struct.error, ValueError):
        return None
    cls = "logical" if word & 0x200 else _CLASSES.get(word & 0xFF, "unknown")
    return name.decode("latin-1"), tuple(int(d) for d in shape), cls


def scan_v5(path: Path, limit: int = MAX_MAT_EXPANDED_BYTES) -> tuple[int, list[tuple[str, tuple[int, ...], str]]] | None:
    """(what the variables of a MATLAB v5 file expand to, the (name, shape, class) of each): read in a stream,
    the expansion counted and discarded (counting stops past ``limit``).  None: not a v5 file (v4: what it holds
    is on disk; v7.3: refused by scipy).  A damaged stream stops the scan (scipy's reader then says what is wrong).
    """
    with open(path, "rb") as fh:
        head = fh.read(128)
        if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
            return None
        order = "<" if head[126:128] == b"IM" else ">"
        if struct.unpack(order + "H", head[124:126])[0] != 0x0100:
            return None
        total = 0
        found: list[tuple[str, tuple[int, ...], str]] = []
        while total <= limit:
            tag = fh.read(8)
            if len(tag) < 8:
                break
            mdtype, n_bytes = struct.unpack(order + "II", tag)
            if mdtype >> 16:  # a small data element: its data is in its tag
                total += mdtype >> 16
                continue
            if mdtype == _MI_COMPRESSED:
                try:
                    n_out, start = _inflated(fh, n_bytes, limit - total)
                except zlib.error:
                    break
                total += n_out
            else:
                start = tag + fh.read(min(n_bytes, _HEADER_BYTES))
                fh.seek(8 + n_bytes - len(start), 1)
                total += n_bytes
            info = _header(start, order)
            if info is not None:
                found.append(info)
        return total, found


def read_mat_columns(path: Path) -> dict[str, NDArray[np.float64]]:
    """The numeric columns of a ``.mat`` (see the module docstring); DataError if refused or unreadable."""
    from scipy.io import loadmat, whosmat

    try:
        scanned = scan_v5(path)
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc})") from exc
    if scanned is not None and scanned[0] > MAX_MAT_EXPANDED_BYTES:
        raise DataError(f"{path}: its variables expand to more than {MAX_MAT_EXPANDED_BYTES} bytes, the most a .mat "
                        "is read to (MAX_MAT_EXPANDED_BYTES): save a shorter record, or as MCAP or CSV")
    # v5: the headers just read (scipy's whosmat inflates each compressed variable whole); v4: whosmat seeks
    infos = scanned[1] if scanned is not None else _scipy(path, lambda: whosmat(str(path)))
    numeric = [(str(n), tuple(int(d) for d in shape), str(cls)) for n, shape, cls in infos
               if cls in _NUMERIC and len(shape) == 2 and all(d > 0 for d in shape)]
    total = sum(math.prod(shape) for _, shape, _ in numeric)
    if total > MAX_MAT_ELEMENTS:
        name, shape, cls = max(numeric, key=lambda v: math.prod(v[1]))
        raise DataError(f"{path}: its numeric variables hold {total} elements (the largest, {name!r}, a "
                        f"{shape[0]} x {shape[1]} {cls} array); a .mat is read up to {MAX_MAT_ELEMENTS} elements "
                        "(MAX_MAT_ELEMENTS; each becomes a float64): save a shorter record, or as MCAP or CSV")
    if not numeric:
        raise DataError(f"{path}: no numeric vector variables found")
    data = _scipy(path, lambda: loadmat(str(path), squeeze_me=False, variable_names=[n for n, _, _ in numeric]))
    cols: dict[str, NDArray[np.float64]] = {}
    for name in [n for n, _, _ in numeric]:
        val = data.pop(name, None)
        if not isinstance(val, np.ndarray) or val.dtype.kind not in "biuf" or val.ndim != 2 or val.size == 0:
            continue
        if 1 in val.shape:
            cols[name] = np.ascontiguousarray(val.reshape(-1), dtype=np.float64)  # float64: no copy
        else:
            for k in range(val.shape[1]):  # a column at a time: never the whole matrix as float64 beside it
                cols[f"{name}[{k}]"] = np.ascontiguousarray(val[:, k], dtype=np.float64)
        del val
    if not cols:
        raise DataError(f"{path}: no numeric vector variables found")
    return cols
