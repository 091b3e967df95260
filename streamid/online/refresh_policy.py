"""When an online update refreshes the champion's weights and when it reruns the coevolution: the policy.

A frozen setting of a stream (:class:`~streamid.online.stream_config.StreamConfig` ``refresh``; the daemon's
``[defaults.refresh]`` / ``[streams.NAME.refresh]`` tables), applied by :mod:`streamid.online.refresh`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from streamid.errors import ConfigError

__all__ = ["RefreshPolicy"]


@dataclass(frozen=True)
class RefreshPolicy:
    """When updates refresh the champion's weights and when they rerun the coevolution (module docstring).

    Attributes
    ----------
    enabled
        False: every update is a coevolution run (the behaviour before refreshes).
    min_every, max_every
        Bounds of the interval, in updates, between two scheduled coevolution runs (``min_every`` 1: every
        update is one).
    memory_s
        Time constant of the forgetting, in seconds of stream time: a sample ``memory_s`` old weighs
        ``1/e`` of the newest.
    ridge
        Tikhonov term added to the unit-scaled normal equations' diagonal.
    """

    enabled: bool = True
    min_every: int = 4
    max_every: int = 32
    memory_s: float = 30.0
    ridge: float = 1e-9

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise ConfigError(f"RefreshPolicy.enabled must be true or false; got {self.enabled!r}")
        for name in ("min_every", "max_every"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"RefreshPolicy.{name} must be an integer >= 1 (updates); got {v!r}")
        if self.max_every < self.min_every:
            raise ConfigError(f"RefreshPolicy.max_every must be >= min_every ({self.min_every}); got {self.max_every!r}")
        if not (isinstance(self.memory_s, (int, float)) and math.isfinite(self.memory_s) and self.memory_s > 0):
            raise ConfigError(f"RefreshPolicy.memory_s must be a number of seconds > 0; got {self.memory_s!r}")
        if not (isinstance(self.ridge, (int, float)) and 0 < self.ridge < 1):
            raise ConfigError(f"RefreshPolicy.ridge must be a number in (0, 1); got {self.ridge!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the status shows it)."""
        return dataclasses.asdict(self)
