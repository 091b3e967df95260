"""Online identification of a stream, as a library: no threads, no I/O, no clock.

:class:`OnlineIdentifier` takes samples (``push``, ``learn_many``, ``learn_one``), owns the
window, its checks, the pending queue, the warm/cold policy, acceptance and versions, and
identifies when the caller says so (``update``, or ``next_job`` / ``UpdateJob.run`` /
``finish`` on a thread of the caller's choice).  The daemon is its adapter to Zenoh,
threads, disk and Rerun.
"""

from streamid.online.identifier import OnlineIdentifier, Persist, Update
from streamid.online.snapshot import StreamState
from streamid.online.stream_config import StreamConfig
from streamid.online.update import Outcome, Stopped, UpdateJob
from streamid.online.window_types import Event, Window, WindowParams

__all__ = [
    "Event",
    "OnlineIdentifier",
    "Outcome",
    "Persist",
    "Stopped",
    "StreamConfig",
    "StreamState",
    "Update",
    "UpdateJob",
    "Window",
    "WindowParams",
]
