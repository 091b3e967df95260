"""Recorders: write Zenoh traffic and simulated or converted device data to MCAP logs.

``recorders`` depends on ``streamid`` (codec, transport, mcaplog), never the reverse.
"""

from __future__ import annotations

from recorders.recorder import Recorder, RecorderConfig, RecordStats, record

__all__ = ["Recorder", "RecorderConfig", "RecordStats", "record"]
