"""Online identification of a stream, as a library: no threads, no I/O, no clock.

:class:`OnlineIdentifier` takes samples (``push``, ``learn_many``, ``learn_one``), owns the
window, its checks, the pending queue, the warm/cold policy, acceptance and versions, and
identifies when the caller says so (``update``, or ``next_job`` / ``UpdateJob.run`` /
``finish`` on a thread of the caller's choice).  The daemon is its adapter to Zenoh,
threads, disk and Rerun.

Every name is imported on first use: a light module of this package (the snapshot the daemon's
state store reads and writes) can be imported without the identifier and the engine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from streamid._lazy import lazy_exports

if TYPE_CHECKING:
    from streamid.online.identifier import OnlineIdentifier, Persist, Update
    from streamid.online.refresh_policy import RefreshPolicy
    from streamid.online.snapshot import StreamState
    from streamid.online.stream_config import StreamConfig
    from streamid.online.update import Outcome, Stopped, UpdateJob
    from streamid.online.window_types import Event, Window, WindowParams

#: Where each exported name lives.
_EXPORTS = {
    "Event": "streamid.online.window_types",
    "OnlineIdentifier": "streamid.online.identifier",
    "Outcome": "streamid.online.update",
    "Persist": "streamid.online.identifier",
    "RefreshPolicy": "streamid.online.refresh_policy",
    "Stopped": "streamid.online.update",
    "StreamConfig": "streamid.online.stream_config",
    "StreamState": "streamid.online.snapshot",
    "Update": "streamid.online.identifier",
    "UpdateJob": "streamid.online.update",
    "Window": "streamid.online.window_types",
    "WindowParams": "streamid.online.window_types",
}

__all__ = [
    "Event",
    "OnlineIdentifier",
    "Outcome",
    "Persist",
    "RefreshPolicy",
    "Stopped",
    "StreamConfig",
    "StreamState",
    "Update",
    "UpdateJob",
    "Window",
    "WindowParams",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals(), __all__)
