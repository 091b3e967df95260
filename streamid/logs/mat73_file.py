"""MATLAB v7.3 ``.mat`` files (HDF5 inside; ``save -v7.3``, the default for large exports), read with h5py.

The only module of streamid that imports ``h5py`` (imported on first use: ``pip install 'streamid[lab]'``).
Columns as for v4-v7.2 files (:func:`streamid.logs.datafile.load_table`): a numeric vector variable is one column,
a matrix ``X`` of ``N x k`` gives ``X[0] .. X[k-1]``; a struct's fields are ``s.field`` (a Simulink
"structure with time" export gives ``s.time`` and ``s.signals.values[0]``...).  Text, cell and complex variables are
listed but refused when used (not numbers).  HDF5 stores MATLAB's column-major arrays transposed; that is undone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.logs.table import Table

__all__ = ["read_mat73_table"]

_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "logical"}
#: Variables and struct fields visited at most (a hostile file could nest or list without end).
MAX_VARIABLES = 10_000
_MAX_DEPTH = 8


def _class(node: Any) -> str:
    c = node.attrs.get("MATLAB_class", b"")
    return c.decode("ascii", "replace") if isinstance(c, bytes) else str(c)


def _walk(path: Path, group: Any, prefix: str, depth: int, cols: dict[str, NDArray[np.float64]],
          unreadable: dict[str, str], seen: list[int]) -> None:
    import h5py

    for key in group:
        if key.startswith("#"):  # "#refs#", "#subsystem#": MATLAB's own bookkeeping
            continue
        seen[0] += 1
        if seen[0] > MAX_VARIABLES:
            raise DataError(f"{path}: more than {MAX_VARIABLES} variables and struct fields; not read")
        node = group[key]
        name = f"{prefix}{key}"
        cls = _class(node)
        if isinstance(node, h5py.Group):
            if depth < _MAX_DEPTH:
                _walk(path, node, name + ".", depth + 1, cols, unreadable, seen)
            continue
        if cls not in _NUMERIC or node.dtype.kind not in "biuf" or "MATLAB_empty" in node.attrs:
            unreadable[name] = (f"{path}: the variable {name!r} is a MATLAB {cls or node.dtype} "
                                f"{'empty array' if 'MATLAB_empty' in node.attrs else 'value'}, not numbers")
            cols[name] = np.full(1, np.nan)
            continue
        a = np.asarray(node[()], dtype=np.float64)
        if a.ndim != 2 or a.size == 0:
            continue
        a = a.T  # HDF5 holds MATLAB's N x k as k x N
        if 1 in a.shape:
            cols[name] = a.reshape(-1)
        else:
            for k in range(a.shape[1]):
                cols[f"{name}[{k}]"] = np.ascontiguousarray(a[:, k])


def read_mat73_table(path: Path) -> Table:
    """Every numeric vector of a MATLAB v7.3 file as a column.

    Raises
    ------
    DataError
        h5py missing, a damaged file, no numeric vector.
    """
    try:
        import h5py
    except ImportError:
        from streamid.logs.timed import needs_library

        raise needs_library("h5py", "MATLAB v7.3 (HDF5) .mat files") from None
    cols: dict[str, NDArray[np.float64]] = {}
    unreadable: dict[str, str] = {}
    try:
        with h5py.File(path, "r") as f:
            _walk(path, f, "", 0, cols, unreadable, [0])
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises OSError, KeyError, ValueError... on a damaged file
        from streamid.logs.timed import why_text

        raise DataError(f"{path}: not a readable MATLAB v7.3 (HDF5) .mat file ({why_text(exc)}); a cut or damaged "
                        "file is not read") from None
    usable = {k: v for k, v in cols.items() if k not in unreadable}
    if not usable:
        raise DataError(f"{path}: no numeric vector variables found (MATLAB v7.3 file"
                        + (f"; not numbers: {', '.join(sorted(unreadable)[:20])})" if unreadable else ")"))
    size = len(next(iter(usable.values())))  # the table's length is a numeric column's, placeholders after
    cols = {**usable, **{k: np.full(size, np.nan) for k in unreadable}}
    return Table(str(path), cols, meta={"lengths": {k: len(v) for k, v in usable.items()}, "format": "mat v7.3"},
                 unreadable=unreadable)
