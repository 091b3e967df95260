"""The streaming identification daemon: Zenoh in, warm-started CoEA, models out.

Data flows one way: :mod:`streamid.transport` delivers payloads, the receiving
path decodes them and appends them to a per-stream :class:`WindowBuffer`
(:mod:`streamid.daemon.window`); closed windows are identified off the
receiving path by :mod:`streamid.daemon.worker`; models are published by
:mod:`streamid.daemon.service` and drawn by :mod:`streamid.viz`.
"""

from __future__ import annotations

from streamid.daemon.window import Window, WindowBuffer, WindowParams

__all__ = ["Window", "WindowBuffer", "WindowParams"]
