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
from streamid.online.refresh_policy import RefreshPolicy
from streamid.online.window_types import DEFAULT_MAX_PENDING_S, MAX_PENDING_WINDOWS, WindowParams

__all__ = ["StreamConfig", "ONLINE_LONG_LINEAR", "ONLINE_REFINE", "ONLINE_SELECTION", "ONLINE_SELECTIONS",
           "ENGINE_RESERVED"]

#: How an update may choose the model of its run (``engine.selection``).
ONLINE_SELECTIONS = ("fitness", "fr_est")
#: The online default of ``engine.selection``: the candidate (the run's best pair and its final population) with the
#: best free run on the window's estimation part, within the data's range. The paper's ``"fitness"`` (the lowest
#: one-step-ahead error) is a setting away. Measured (docs/benchmarks.md, issue 12): on the simulated MR damper's drift
#: sweep (64 seeds) every change got a new champion within 5 s (62 of 64 with ``"fitness"``) and the slowest detection
#: took 3.6 s (11.6 s), with no false alarm before a change nor on the stationary records; the champions' free runs
#: are better, so their level's spread is smaller and a 20 % change stands out sooner.
ONLINE_SELECTION = "fr_est"
#: The online default of ``engine.long_linear``: the largest order of the dense linear ARX part an update's model may
#: get (:func:`streamid.online.update.long_linear_part`: only orders above the lag search's, and only where the network
#: explains less than 95 % of the window's estimation part in free run); as offline (``CoEAConfig.recommended``).
#: Measured (docs/benchmarks.md, issue 12): the F-16 log x2, every challenger's held-out free-run R^2, medians
#: 0.571 / 0.042 / 0.154 -> 0.882 / 0.893 / 0.900; the simulated damper's drift sweep unchanged (32 of 32 within 3 s).
#: 0: off.
ONLINE_LONG_LINEAR = 512
#: The online default of ``engine.refine_iterations``: each coevolution run's model has its weights fitted to its free
#: run, judged out of sample (:func:`streamid.engine.choice.refine.refine_judged`: refined on the first half of the window's
#: estimation part, made only if that free-runs better over the second half); as offline. Measured
#: (docs/benchmarks.md, "Online refinement"): 2 kHz damper windows scored on a common record of another excitation,
#: 30 seeds, no seed lower (10,000 samples: median 0.9297 -> 0.9397; 100,000: 0.9253 -> 0.9369) for 0.06-0.3 s
#: more per update; the drift sweep unchanged (30 of 32 detected within 3 s, 32 new champions within 5 s). 0: off.
ONLINE_REFINE = 10
# Fields of CoEAConfig the daemon sets itself (generations: cold/warm; restarts: warm starts need one run).
ENGINE_RESERVED = ("generations", "restarts", "neurons", "max_lag_y", "max_lag_u", "population")


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
        Floors of a valid model: a challenger is published only if its
        one-step-ahead and free-run R^2 on the held-out part reach them, and a
        champion whose figures on current data fall below them is replaced by any
        better challenger (:mod:`streamid.online.acceptance`).  Defaults 0.5 and
        0.5: a model that does not explain half of the output's variance in free
        run is not worth serving to a controller, and no system of the tuning
        suite needs a lower floor (docs/method.md).
    challenger_margin
        How much higher a challenger's free-run R^2 must be than the champion's,
        on the same held-out data, to replace a valid champion (default 0.005:
        about the spread of R^2 between restarts on a few seconds of data, so
        a controller is not handed a new model for a difference that is noise).
        Negative: a challenger up to that much worse still replaces the champion
        (-1: every valid challenger does, one model per window as in the paper).
    drift_detection
        Watch the output's level relative to the champion's short free runs on
        incoming data with a CUSUM test (:mod:`streamid.online.drift`); on a
        drift, the next identification of that output uses only the data after
        the estimated change, runs ``drift_generations`` generations, and the
        champion recalibrated to the new level competes with it
        (:mod:`streamid.online.recalibrate`).
    drift_generations
        Generations of the identification after a drift (default 100, warm
        from the previous populations: the lag structure usually survives a
        parameter change, the centres and weights must move).
    max_abs_value
        Samples of larger magnitude are refused as absurd.
    cold_after_failures
        After this many failed updates in a row the next run starts cold.
    max_pending_windows, max_pending_bytes
        Bounds of the queue of closed windows waiting for identification
        (:mod:`streamid.online.pending`).  While stream time runs faster than
        the caller's clock (a replayed log, ``learn_many`` on a record), every
        window waits its turn, oldest first, up to these bounds (default 1000
        windows and 64 MiB per stream, the samples of overlapping windows held
        once; beyond them the oldest waiting window is coalesced, counted).  1:
        always only the newest.
    max_pending_s
        A live stream (stream time at about the caller's clock) that falls behind
        keeps its waiting windows too, in order, while the oldest ends at most this
        many seconds of stream time before the newest (default
        :data:`~streamid.online.window_types.DEFAULT_MAX_PENDING_S`, 120; older ones are
        coalesced, counted); the identifier works through such a backlog with
        refreshes of the champion (a coevolution run due by schedule waits until
        it is drained).  0: a live stream keeps only its newest window.
    engine
        Other :class:`~streamid.engine.CoEAConfig` fields, as ``(name, value)`` pairs. ``selection`` is
        ``"fr_est"`` online unless set here (:data:`ONLINE_SELECTION`; ``"fitness"``: the paper's best pair).
        ``long_linear`` is 512 online unless set here (:data:`ONLINE_LONG_LINEAR`; 0: off): where the network's
        free run explains less than 95 % of a window, a dense linear ARX part longer than its lags competes.
        ``run_ensembles`` has no
        effect online: an update is one run (warm starts need one), never a mean of runs (K x its time: piezo 0.5 s).
        ``refine_iterations`` is 10 online unless set here (:data:`ONLINE_REFINE`; 0: off): each coevolution
        run's weights are fitted to its free run, judged out of sample (:mod:`streamid.engine.choice.refine`).
        ``direct_terms = "test"`` (off online unless set here) offers ``u(t)`` to a cold run whose window shows a
        response within the sample (:mod:`streamid.engine.search.feedthrough`; warm runs keep their populations'
        candidates); measured on the bundled MR damper log, x4 at max speed, every window: published models'
        held-out free-run R^2 median 0.9805 (0.9790 without) but worst 0.910 (0.967 without), so not the default.
    refresh
        When an update refreshes the champion's weights instead of rerunning the coevolution
        (:class:`~streamid.online.refresh_policy.RefreshPolicy`, :mod:`streamid.online.refresh`; ``enabled=False``:
        every update is a coevolution run).
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
    min_r2_fr: float = 0.5
    challenger_margin: float = 0.005
    drift_detection: bool = True
    drift_generations: int = 100
    max_abs_value: float = 1e12
    cold_after_failures: int = 3
    max_pending_windows: int = MAX_PENDING_WINDOWS
    max_pending_bytes: int = 64 * 2**20
    max_pending_s: float = DEFAULT_MAX_PENDING_S
    engine: tuple[tuple[str, Any], ...] = ()
    refresh: RefreshPolicy = RefreshPolicy()

    def __post_init__(self) -> None:
        self.window_params()  # geometry and names checked once, here
        sel = dict(self.engine).get("selection", ONLINE_SELECTION)  # named as the configuration names it
        if sel in ONLINE_SELECTIONS:
            self.coea_config(cold=True)  # every engine field checked here, at start (ConfigError naming it)
        else:
            raise ConfigError(
                f"engine.selection must be one of {list(ONLINE_SELECTIONS)} online (one run per update: "
                f"'fitness' = lowest one-step-ahead error, 'fr_est' = best free run on the estimation part); got {sel!r}"
            )
        if isinstance(self.refresh, dict):  # as to_dict writes it
            object.__setattr__(self, "refresh", RefreshPolicy(**self.refresh))
        if not isinstance(self.refresh, RefreshPolicy):
            raise ConfigError(f"refresh must be a RefreshPolicy; got {type(self.refresh).__name__}")
        if not 0.05 <= self.validation_fraction <= 0.9:
            raise ConfigError(f"validation_fraction must be a number in [0.05, 0.9]; got {self.validation_fraction!r}")
        if self.output is not None and self.outputs is not None and self.output not in self.outputs:
            raise ConfigError(f"output must be one of outputs {list(self.outputs)}; got {self.output!r}")
        for name in ("cold_generations", "warm_generations", "drift_generations"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be an integer >= 1; got {getattr(self, name)!r}")
        if self.cold_after_failures < 1:
            raise ConfigError(f"cold_after_failures must be an integer >= 1; got {self.cold_after_failures!r}")
        if self.seed < 0:  # numpy seeds are non-negative: every update would fail
            raise ConfigError(f"seed must be an integer >= 0; got {self.seed!r}")
        for name in ("min_r2_osa", "min_r2_fr"):  # R^2 never exceeds 1: no model could ever be published
            if not getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must be a number <= 1 (R^2 never exceeds 1); got {getattr(self, name)!r}")

        if not (isinstance(self.challenger_margin, (int, float)) and -1.0 <= self.challenger_margin <= 1.0):
            raise ConfigError(
                f"challenger_margin must be a number in [-1, 1] (an R^2 difference); got {self.challenger_margin!r}")
        if not isinstance(self.drift_detection, bool):
            raise ConfigError(f"drift_detection must be true or false; got {self.drift_detection!r}")

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
            max_pending_bytes=self.max_pending_bytes,
            max_pending_s=self.max_pending_s,
        )

    def coea_config(self, *, cold: bool, generations: int | None = None) -> CoEAConfig:
        """The engine configuration of a cold or a warm run (``generations``: an escalated budget)."""
        return CoEAConfig(
            neurons=self.neurons,
            max_lag_y=self.max_lag_y,
            max_lag_u=self.max_lag_u,
            population=self.population,
            generations=generations or (self.cold_generations if cold else self.warm_generations),
            **{"selection": ONLINE_SELECTION, "long_linear": ONLINE_LONG_LINEAR, "refine_iterations": ONLINE_REFINE,
               **dict(self.engine)},
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON/TOML-ready dict (None values left out)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None or f.name in ("engine", "refresh"):
                continue
            out[f.name] = list(v) if isinstance(v, tuple) else v
        if self.engine:
            out["engine"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.engine}
        out["refresh"] = self.refresh.to_dict()
        return out
