"""The streaming identification daemon: Zenoh in, warm-started CoEA, models out.

Data flows one way: :mod:`streamid.transport.zenoh_bus` delivers payloads, the receiving
path decodes them and appends them to a per-stream :class:`WindowBuffer`
(:mod:`streamid.online.window`); closed windows are identified off the
receiving path by :mod:`streamid.online.update`; models are published by
:mod:`streamid.daemon.service` and drawn by :mod:`streamid.viz.rerun_view`.
"""

from __future__ import annotations

from streamid.online.window import Window, WindowBuffer, WindowParams

__all__ = ["Window", "WindowBuffer", "WindowParams"]
