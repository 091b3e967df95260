"""Replay: play an MCAP log back onto Zenoh with its original timing (scaled) or at full speed.

``replay`` depends on ``streamid`` (codec, transport, mcaplog), never the reverse.
"""

from __future__ import annotations

from replay.player import ReplayConfig, ReplayReport, replay_log

__all__ = ["ReplayConfig", "ReplayReport", "replay_log"]
