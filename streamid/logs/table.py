"""A data file's numeric columns, with sample times when it has them: what every reader of ``streamid.logs`` returns
(a module of its own, so that the readers of each format and :mod:`streamid.logs.datafile`, which dispatches to
them, import it and not each other)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError

__all__ = ["Table", "SHOWN_NAMES"]

#: Names a message lists of what a file holds (its first ones: a file of thousands of variables stays one line).
SHOWN_NAMES = 20


@dataclass(frozen=True)
class Table:
    """Numeric columns of a data file (equal lengths), with sample times when the file has them."""

    path: str
    columns: dict[str, NDArray[np.float64]]
    t_ns: NDArray[np.int64] | None = None
    period_ns: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    #: columns that cannot be read as numbers, and why (raised by :meth:`column`, only when one is used)
    unreadable: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def column(self, name: str) -> NDArray[np.float64]:
        """One column; :class:`DataError` naming the available ones if unknown."""
        if name not in self.columns and name not in self.unreadable:
            names = sorted(self.meta.get("columns", self.columns))
            more = f" and {len(names) - SHOWN_NAMES} more" if len(names) > SHOWN_NAMES else ""
            raise DataError(f"unknown column {name!r} in {self.path}; available columns: {names[:SHOWN_NAMES]}{more}")
        if name in self.unreadable:
            raise DataError(self.unreadable[name])
        return self.columns[name]
