"""Settings of one stream's online identification (frozen, validated, every field with a default).

:class:`StreamConfig` is what an :class:`~streamid.online.OnlineIdentifier`
takes; the daemon reads one per stream from its TOML file
(:mod:`streamid.daemon.config`).  A bad value raises
:class:`~streamid.errors.ConfigError` naming the field, the accepted form and
the value.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from streamid.engine.settings import CoEAConfig
from streamid.errors import ConfigError
from streamid.online.window_types import WindowParams

__all__ = ["StreamConfig", "ONLINE_SELECTIONS", "ENGINE_RESERVED"]

#: How an update may choose the model of its run (``engine.selection``).
ONLINE_SELECTIONS = ("fitness", "fr_est")
# Fields of CoEAConfig the daemon sets itself (generations: cold/warm; restarts: warm starts need one run).
ENGINE_RESERVED = ("generations", "restarts", "workers", "neurons", "max_lag_y", "max_lag_u", "population")


@dataclass(frozen=True)
class StreamConfig:
    """Identification settings of one stream (every field has a default).

    Attributes
    ----------
    window_s, window_samples
        Window length in seconds of stream time, or in samples (at most one).
    update_every_s, update_every_samples
        Re-identify every this many seconds of stream time / new samples.
    validation_fraction
        Newest fraction of each window held out for validation.
    cold_generations, warm_generations
        Generations of the first (cold) run and of the warm-started updates.
    neurons, max_lag_y, max_lag_u, population
        Model and search size (see :class:`~streamid.engine.CoEAConfig`).
    seed
        Seed of every random draw of this stream (with the stream name and version).
    inputs, outputs
        Signal names to use (None: as found in the batches).
    output
        Which output is modelled when there are several (None: the first).
    min_r2_osa, min_r2_fr
        A new model is published only if its one-step-ahead and free-run R^2 on
        the validation part reach these; otherwise the stream is marked degraded
        and the previous model stays current.
    max_abs_value
        Samples of larger magnitude are refused as absurd.
    cold_after_failures
        After this many failed updates in a row the next run starts cold.
    max_pending_windows
        How many closed windows may wait while an identification runs (1 to
        1000).  1 (default): a newer window replaces the waiting one, the right
        choice for a live stream.  More: e.g. a log replayed at max speed gets
        every window identified, in order, up to this many behind; beyond it
        the oldest waiting is dropped (coalesced).  Memory bound: this many
        times ``window_samples * (inputs + outputs) * 8`` bytes per stream.
    engine
        Other :class:`~streamid.engine.CoEAConfig` fields, as ``(name, value)`` pairs.
    """

    window_s: float | None = None
    window_samples: int | None = None
    update_every_s: float | None = None
    update_every_samples: int | None = None
    validation_fraction: float = 0.3
    cold_generations: int = 400
    warm_generations: int = 30
    neurons: int = 10
    max_lag_y: int = 10
    max_lag_u: int = 10
    population: int = 20
    seed: int = 0
    inputs: tuple[str, ...] | None = None
    outputs: tuple[str, ...] | None = None
    output: str | None = None
    min_r2_osa: float = 0.5
    min_r2_fr: float = -1.0
    max_abs_value: float = 1e12
    cold_after_failures: int = 3
    max_pending_windows: int = 1
    engine: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        self.window_params()  # geometry and names checked once, here
        sel = self.coea_config(cold=True).selection
        if sel not in ONLINE_SELECTIONS:
            raise ConfigError(
                f"engine.selection must be one of {list(ONLINE_SELECTIONS)} online (one run per update: "
                f"'fitness' = lowest one-step-ahead error, 'fr_est' = best free run on the estimation part); got {sel!r}"
            )
        if not 0.05 <= self.validation_fraction <= 0.9:
            raise ConfigError(f"validation_fraction must be a number in [0.05, 0.9]; got {self.validation_fraction!r}")
        if self.output is not None and self.outputs is not None and self.output not in self.outputs:
            raise ConfigError(f"output must be one of outputs {list(self.outputs)}; got {self.output!r}")
        for name in ("cold_generations", "warm_generations"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be an integer >= 1; got {getattr(self, name)!r}")
        if self.cold_after_failures < 1:
            raise ConfigError(f"cold_after_failures must be an integer >= 1; got {self.cold_after_failures!r}")
        if self.seed < 0:  # numpy seeds are non-negative: every update would fail
            raise ConfigError(f"seed must be an integer >= 0; got {self.seed!r}")
        for name in ("min_r2_osa", "min_r2_fr"):  # R^2 never exceeds 1: no model could ever be published
            if not getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must be a number <= 1 (R^2 never exceeds 1); got {getattr(self, name)!r}")

    def window_params(self) -> WindowParams:
        """The window geometry of this stream."""
        return WindowParams(
            window_s=self.window_s,
            window_samples=self.window_samples,
            hop_s=self.update_every_s,
            hop_samples=self.update_every_samples,
            inputs=self.inputs,
            outputs=self.outputs,
            max_abs_value=self.max_abs_value,
            max_pending_windows=self.max_pending_windows,
        )

    def coea_config(self, *, cold: bool) -> CoEAConfig:
        """The engine configuration of a cold or a warm run."""
        return CoEAConfig(
            neurons=self.neurons,
            max_lag_y=self.max_lag_y,
            max_lag_u=self.max_lag_u,
            population=self.population,
            generations=self.cold_generations if cold else self.warm_generations,
            **dict(self.engine),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON/TOML-ready dict (None values left out)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None or f.name == "engine":
                continue
            out[f.name] = list(v) if isinstance(v, tuple) else v
        if self.engine:
            out["engine"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.engine}
        return out
