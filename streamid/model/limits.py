"""Bounds on a model read from a file, the network or a saved state, checked before any array is built.

A model document is data from elsewhere (a file someone sent, a model update on the bus, a state
file or a state handed over by another daemon).  What it costs to hold and to evaluate grows with
its neurons, regressors and lags, so each has a bound, checked on the parsed JSON (counts and
integers only) before any numpy array is made:

==========================  =================  ==================================================
bound                       value              why this value
==========================  =================  ==================================================
:data:`MAX_MODEL_BYTES`     16 MiB             JSON text of a model file read (the engine's largest,
                                               1000 neurons x 200 regressors, is ~5 MB)
:data:`MAX_DEPTH`           32                 JSON nesting (a model update with an ensemble is 7)
:data:`MAX_NEURONS`         1000               per network: the engine's own ``neurons`` bound
:data:`MAX_REGRESSORS`      4096               per network and per long linear part
:data:`MAX_LAG`             10000              any regressor's lag (the engine's lags are <= 1000)
:data:`MAX_INPUTS`          1024               inputs of the normalisation (a stream has <= 64)
:data:`MAX_PARAMETERS`      1,000,000          numbers of all networks together (8 MB as float64)
:data:`MIN_WIDTH`           1e-150             ``1 / (2 w^2)`` must be a finite float64
:data:`MIN_SPAN`            1e-60              a signal's ``high - low`` (the daemon's own rule)
==========================  =================  ==================================================

Evaluating a model within these bounds costs at most ~64 MB per block of one-step-ahead rows
(:func:`osa_block_rows`), whatever the record's length.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from streamid.errors import ModelFormatError
from streamid.wire.names import check_model_names

__all__ = ["MAX_DEPTH", "MAX_INPUTS", "MAX_LAG", "MAX_MODEL_BYTES", "MAX_NEURONS", "MAX_PARAMETERS", "MAX_REGRESSORS",
           "MIN_SPAN", "MIN_WIDTH", "OSA_BLOCK_BYTES", "check_model_document", "json_depth", "osa_block_rows",
           "parse_model_json"]

MAX_MODEL_BYTES = 16 * 1024 * 1024
MAX_DEPTH = 32
MAX_NEURONS = 1000
MAX_REGRESSORS = 4096
MAX_LAG = 10_000
MAX_INPUTS = 1024
MAX_PARAMETERS = 1_000_000
MIN_WIDTH = 1e-150
MIN_SPAN = 1e-60
#: Bytes of the temporaries of one block of one-step-ahead rows.
OSA_BLOCK_BYTES = 64 * 1024 * 1024
#: Rows of one chunk of streamed work over a record (one-step-ahead blocks, free-run scoring, the refinement's
#: Jacobian, validation): memory bounded by it, not by the record. An offline estimation record with more
#: regressor rows than this takes the bounded path (:func:`streamid.engine.search.rows.long_record_rows`).
CHUNK_ROWS = 65_536

_ENSEMBLES = ("streamid.model/3", "streamid.model/5", "streamid.model/6")


def json_depth(doc: Any, limit: int = MAX_DEPTH) -> int:
    """The nesting depth of a parsed JSON value (a scalar: 0), counted without recursion up to ``limit + 1``."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(doc, 1)] if isinstance(doc, (list, dict)) else []
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        if deepest > limit:
            return deepest
        for child in (node.values() if isinstance(node, dict) else node):
            if isinstance(child, (list, dict)):
                stack.append((child, depth + 1))
    return deepest


def parse_model_json(text: str | bytes, source: str = "a model document") -> Any:
    """``json.loads`` of a model document within :data:`MAX_MODEL_BYTES` and :data:`MAX_DEPTH` (else ModelFormatError)."""
    if len(text) > MAX_MODEL_BYTES:
        raise ModelFormatError(f"{source} holds {len(text)} bytes; a model document is at most {MAX_MODEL_BYTES} "
                               "bytes (16 MiB)")
    try:
        doc = json.loads(text)
    except RecursionError:
        raise ModelFormatError(f"{source} nests JSON deeper than Python can parse; a model document nests at most "
                               f"{MAX_DEPTH} levels") from None
    except (ValueError, TypeError, MemoryError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise ModelFormatError(f"{source} must be JSON text; parsing failed: {str(exc)[:300]}") from None
    depth = json_depth(doc)
    if depth > MAX_DEPTH:
        raise ModelFormatError(f"{source} nests JSON {depth}+ levels deep; a model document nests at most {MAX_DEPTH}")
    return doc


def _count(d: Mapping[str, Any], key: str, bound: int, where: str, what: str) -> int:
    v = d.get(key)
    n = len(v) if isinstance(v, (list, dict, str)) else 0
    if n > bound:
        raise ModelFormatError(f"model field {where}{key!r} holds {n} {what}; a model has at most {bound} (checked "
                               "before anything is built)")
    return n


def _network(d: Mapping[str, Any], where: str) -> int:
    """Check one network's counts and lags; returns its number of parameters."""
    m = _count(d, "widths", MAX_NEURONS, where, "neurons")
    _count(d, "weights", MAX_NEURONS, where, "weights (one per neuron)")
    _count(d, "centres", MAX_NEURONS, where, "centre rows (one per neuron)")
    k = _count(d, "regressors", MAX_REGRESSORS, where, "regressors")
    q = _count(d, "linear_regressors", MAX_REGRESSORS, where, "linear regressors")
    lin = _count(d, "linear", MAX_REGRESSORS + 1, where, "linear coefficients")
    for key in ("regressors", "linear_regressors"):
        regs = d.get(key)
        for i, r in enumerate(regs if isinstance(regs, list) else ()):
            lag = r.get("lag") if isinstance(r, Mapping) else None
            if isinstance(lag, int) and not isinstance(lag, bool) and not 0 <= lag <= MAX_LAG:
                got = str(lag) if len(str(lag)) <= 30 else f"an integer of {len(str(lag))} digits"
                raise ModelFormatError(f"model field {where}{key}[{i}].lag must be in [0, {MAX_LAG}]; got {got}")
    return m * (k + 2) + max(lin, q + 1 if q else 0)


def check_model_document(d: Any) -> None:
    """Refuse a model document beyond the bounds above (ModelFormatError naming the field, the count and the bound).

    Only counts and integers of the parsed JSON are looked at; malformed fields are left to the full parser.
    """
    if not isinstance(d, Mapping):
        return
    norm = d.get("normalisation")
    if isinstance(norm, Mapping):
        _count(norm, "u_low", MAX_INPUTS, "'normalisation'.", "inputs")
        _count(norm, "u_high", MAX_INPUTS, "'normalisation'.", "inputs")
    _count(d, "inputs", MAX_INPUTS, "", "input names")
    check_model_names(d)  # the one rule for names (streamid.wire.names), on every path a model takes
    if d.get("format") in _ENSEMBLES:
        members = d.get("members")
        if not isinstance(members, list):
            return
        if len(members) > 32:  # ensemble.MAX_MEMBERS: refused by the ensemble's parser before any member is read
            return
        total = sum(_network(e, f"'members[{i}]'.") for i, e in enumerate(members) if isinstance(e, Mapping))
    else:
        total = _network(d, "")
    if total > MAX_PARAMETERS:
        raise ModelFormatError(f"the model holds {total} parameters (neurons x (regressors + 2) + linear part, over "
                               f"all its networks); a model has at most {MAX_PARAMETERS}")
    depth = json_depth(d)  # (after the counts: the walk is as long as the document)
    if depth > MAX_DEPTH:
        raise ModelFormatError(f"the model document nests {depth}+ levels deep; a model document nests at most "
                               f"{MAX_DEPTH}")


def osa_block_rows(neurons: int, regressors: int, most: int) -> int:
    """Rows of a one-step-ahead block whose temporaries (~3 floats per neuron and regressor) fit OSA_BLOCK_BYTES."""
    per_row = 8 * 3 * (max(1, neurons) + max(1, regressors))
    return max(64, min(most, OSA_BLOCK_BYTES // per_row))
