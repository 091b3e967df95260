"""Device logs: MCAP files of Zenoh traffic, their arrays, the bundled logs and user data files.

:mod:`streamid.logs.mcap_files` is the only module of streamid that imports ``mcap``.
"""

from streamid.logs.arrays import LogArrays, read_log_arrays, write_arrays_log
from streamid.logs.bundled import bundled_log, bundled_logs
from streamid.logs.mcap_files import LOG_FORMAT, LogInfo, LogMessage, LogReader, LogWriter, iter_log, log_info

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
