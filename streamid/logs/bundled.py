"""The logs shipped inside the package (``streamid/data/*.mcap``), by name."""

from __future__ import annotations

import difflib
from importlib import resources
from pathlib import Path

from streamid.errors import LogError

__all__ = ["bundled_log", "bundled_logs", "data_file"]


def bundled_logs() -> list[str]:
    """Names of the logs shipped in ``streamid/data`` (without ``.mcap``)."""
    root = resources.files("streamid") / "data"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".mcap"))


def bundled_log(name: str) -> Path:
    """Path of a log shipped with streamid, e.g. ``bundled_log("mr_damper")``."""
    stem = name[:-5] if name.endswith(".mcap") else name
    res = resources.files("streamid") / "data" / f"{stem}.mcap"
    path = Path(str(res))
    if not path.is_file():
        names = bundled_logs()
        close = difflib.get_close_matches(stem, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise LogError(f"bundled log name must be one of {names}; got {name!r}{hint}")
    return path


def data_file(name: str, what: str = "DATA") -> Path:
    """An existing file, or the log shipped with streamid of that name (as ``streamid replay`` takes it).

    Raises
    ------
    LogError
        Neither: the message lists the bundled logs (and the closest name).
    """
    path = Path(name)
    if path.exists():
        return path
    if "/" in name or "\\" in name or not name:
        raise LogError(f"{what} must be an existing file or a bundled log name ({', '.join(bundled_logs())}); "
                       f"{name!r} does not exist")
    try:
        return bundled_log(name)
    except LogError as exc:
        raise LogError(f"{what}: {name!r} does not exist here, and {exc}") from None
