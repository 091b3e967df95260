"""ASAM MDF measurement files (``.mf4``, ``.mdf``: dSPACE ControlDesk, Vector CANape, ETAS INCA), read with asammdf.

The only module of streamid that imports ``asammdf`` (imported on first use: ``pip install 'streamid[lab]'``).

A channel is named by its name (``EngineSpeed``); where a name repeats in several channel groups, by its name and
group index, ``EngineSpeed@2`` (the message of an ambiguous name lists the groups).  Values are the physical values
(the channel's conversion applied, as the measurement tool shows them); a channel whose conversion gives text (a
value-to-text table) is refused as not numeric.  Each channel keeps its group's time channel (seconds, as MDF stores
it, to integer ns), and the channels are put on the output's own timestamps by :mod:`streamid.logs.timed`'s rule.
"""

from __future__ import annotations

import gc
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from streamid.errors import DataError
from streamid.logs.table import Table

__all__ = ["read_mdf_table"]

_GROUP = re.compile(r"^(.*)@(\d+)$")


def _open(path: Path) -> Any:
    try:
        import asammdf
    except ImportError:
        from streamid.logs.timed import needs_library

        raise needs_library("asammdf", "MDF (.mf4/.mdf) files") from None
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic not in (b"MDF     ", b"UnFinMF "):  # checked first: asammdf's own refusal leaves a traceback on stderr
        raise DataError(f"{path}: not an ASAM MDF file (it starts with {magic!r}, an MDF file with b'MDF     ')")
    why = ""
    hook = sys.unraisablehook
    sys.unraisablehook = _quiet_asammdf(hook)
    try:
        try:
            return asammdf.MDF(str(path))
        except Exception as exc:  # noqa: BLE001 - asammdf raises many kinds on a damaged file: the file's fault
            from streamid.logs.timed import why_text

            why = why_text(exc)
        gc.collect()  # the half-built reader's __del__ fails (asammdf 8.x) while its error is still quieted
    finally:
        sys.unraisablehook = hook
    raise DataError(f"{path}: not a readable MDF file ({why}); a cut or damaged file is not read")


def _quiet_asammdf(hook: Callable[[Any], object]) -> Callable[[Any], object]:
    """An unraisable-exception hook that drops the errors of asammdf's own ``__del__`` (a reader it failed to
    build cannot close: a traceback on stderr for a file already refused in one line) and passes the rest on."""

    def quiet(u: Any) -> object:
        if str(getattr(u.object, "__module__", "") or "").startswith("asammdf"):
            return None
        return hook(u)

    return quiet


Where = list[tuple[int, int]]  # (channel group, channel index) of each channel a name stands for


def _names(mdf: Any) -> tuple[dict[str, Where], dict[str, Where]]:
    """The data channels (time/master channels left out): by their own names, and by their display names (aliases
    a measurement tool shows, which asammdf also indexes; a display name can stand for several channels)."""
    masters = dict(mdf.masters_db)
    own: dict[str, Where] = {}
    for g, group in enumerate(mdf.groups):
        for i, ch in enumerate(group.channels):
            if masters.get(g) != i:
                own.setdefault(str(ch.name), []).append((g, i))
    alias: dict[str, Where] = {}
    for name, where in mdf.channels_db.items():
        if str(name) not in own:
            found = [(int(g), int(i)) for g, i in where if masters.get(g) != i]
            if found:
                alias[str(name)] = found
    return own, alias


def _listed(names: dict[str, Where]) -> list[str]:
    return [n if len(w) == 1 else f"{n}@{{{','.join(str(g) for g, _ in w)}}}" for n, w in names.items()]


def _locate(path: Path, mdf: Any, names: tuple[dict[str, Where], dict[str, Where]], wanted: str) -> tuple[int, int]:
    """(group, index) of the channel ``NAME`` or ``NAME@GROUP`` (a display name where it names one channel)."""
    own, alias = names
    m = _GROUP.match(wanted)
    name, group = (wanted, None) if wanted in own or wanted in alias or m is None else (m.group(1), int(m.group(2)))
    if name not in own and name in alias:
        channels = sorted({str(mdf.groups[g].channels[i].name) for g, i in alias[name]})
        if len(alias[name]) > 1:
            raise DataError(f"{path}: {name!r} is the display name of {len(alias[name])} channels "
                            f"({', '.join(channels)}): name one of them by its own name")
        name = channels[0]
    if name not in own:
        from streamid.logs.timed import names_line

        raise DataError(f"{path}: no channel {wanted!r} (a channel is NAME, or NAME@GROUP where a name repeats); "
                        + names_line(_listed(own), "channels"))
    where = own[name]
    groups = [g for g, _ in where]
    if group is None:
        if len(where) > 1:
            raise DataError(f"{path}: the channel name {name!r} is in {len(groups)} channel groups ({groups}): name one "
                            f"as {name}@GROUP, e.g. {name}@{groups[0]}")
        group = groups[0]
    elif group not in groups:
        raise DataError(f"{path}: the channel {name!r} is in the channel groups {groups}, not in group {group}: "
                        f"name it as {name}@{groups[0]}")
    if groups.count(group) > 1:
        raise DataError(f"{path}: the channel name {name!r} is {groups.count(group)} times in channel group {group}: "
                        "the channels cannot be told apart by name (rename one in the measurement tool)")
    return group, next(i for g, i in where if g == group)


def read_mdf_table(path: Path, signals: Sequence[str] | None) -> Table:
    """The channels ``signals`` (inputs, then the output) of an MDF file on the output's timestamps.

    Raises
    ------
    DataError
        No signals named (the message lists the file's channels), unknown or ambiguous channel, text values,
        a damaged file, asammdf missing, or the grid rule's refusals (:mod:`streamid.logs.timed`).
    """
    from streamid.logs.timed import Signal, names_line, on_output_grid, why_text

    mdf = _open(path)
    try:
        names = _names(mdf)
        if not signals:
            raise DataError(f"{path}: give the channels to use, --input NAME (once per input) and --output NAME; "
                            + names_line(_listed(names[0]), "channels"))
        got = []
        for wanted in signals:
            group, index = _locate(path, mdf, names, wanted)
            try:
                s = mdf.get(group=group, index=index)
            except Exception as exc:  # noqa: BLE001 - a damaged data block: the file's fault, said in one line
                raise DataError(f"{path}: the channel {wanted!r} cannot be read ({why_text(exc)}): a cut or "
                                "damaged file?") from None
            values = np.asarray(s.samples)
            if values.dtype.kind not in "biuf" or values.ndim != 1:
                kind = "text" if values.dtype.kind in "SUO" else f"{values.dtype} of shape {values.shape[1:]}"
                raise DataError(f"{path}: the channel {wanted!r} holds {kind} values, not numbers (a conversion to "
                                "text?); choose a numeric channel")
            t = np.round(np.asarray(s.timestamps, dtype=np.float64) * 1e9).astype(np.int64)
            if t.size != values.size:
                raise DataError(f"{path}: the channel {wanted!r} has {values.size} values but {t.size} times: "
                                "a damaged file?")
            got.append(Signal(wanted, t, values.astype(np.float64)))
        return on_output_grid(str(path), got[:-1], got[-1], {"format": "mdf", "version": str(mdf.version)})
    finally:
        mdf.close()
