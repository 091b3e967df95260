"""Device logs: MCAP files of Zenoh traffic, their arrays, the bundled logs and user data files.

:mod:`streamid.logs.mcap_files` is the only module of streamid that imports ``mcap``. The names below are imported
on first use (:mod:`streamid._lazy`): ``identify`` on a CSV reads a user data file (``streamid.logs.datafile``) and
needs neither ``mcap`` nor the wire codec (0.1 s of its start).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports

if TYPE_CHECKING:
    from streamid.logs.arrays import LogArrays, read_log_arrays, write_arrays_log
    from streamid.logs.bundled import bundled_log, bundled_logs
    from streamid.logs.mcap_files import LOG_FORMAT, LogInfo, LogMessage, LogReader, LogWriter, iter_log, log_info

_EXPORTS = {
    "LogArrays": "streamid.logs.arrays",
    "read_log_arrays": "streamid.logs.arrays",
    "write_arrays_log": "streamid.logs.arrays",
    "bundled_log": "streamid.logs.bundled",
    "bundled_logs": "streamid.logs.bundled",
    "LOG_FORMAT": "streamid.logs.mcap_files",
    "LogInfo": "streamid.logs.mcap_files",
    "LogMessage": "streamid.logs.mcap_files",
    "LogReader": "streamid.logs.mcap_files",
    "LogWriter": "streamid.logs.mcap_files",
    "iter_log": "streamid.logs.mcap_files",
    "log_info": "streamid.logs.mcap_files",
}

__all__ = [
    "LOG_FORMAT",
    "LogArrays",
    "LogInfo",
    "LogMessage",
    "LogReader",
    "LogWriter",
    "bundled_log",
    "bundled_logs",
    "iter_log",
    "log_info",
    "read_log_arrays",
    "write_arrays_log",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals(), __all__)
