"""The rows an online update's search is evaluated on: the engine's rule (:mod:`streamid.engine.search.rows`).

The rule lives in the engine since offline identification of a record longer than one chunk uses it too
(one rule, not two); this module keeps the online names where the daemon and its documents look for them.
"""

from __future__ import annotations

from streamid.engine.search.rows import ROWS_PER_WEIGHT, SEARCH_ROWS, RowSample, informative_rows, search_row_bound

__all__ = ["ROWS_PER_WEIGHT", "SEARCH_ROWS", "RowSample", "informative_rows", "search_row_bound"]
