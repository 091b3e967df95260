"""Configuration of the identification daemon: frozen dataclasses loaded from TOML.

A configuration file is optional: every setting has an embedded default, so
``streamid daemon`` runs with none.  The file has three kinds of tables::

    [daemon]                  # the service as a whole
    streams = ["bench1"]      # serve these streams (empty: discover streamid/*/samples)
    discover = false          # also serve streams not listed (default: true only when none listed)
    max_streams = 64
    status_every_s = 1.0
    workers = 2               # identification worker threads (2: refreshes on the second core; see docs/daemon.md)
    helper = true             # one evaluation helper process per worker (the second core, idle CPU only)
    retain_memory = true      # keep freed working memory for reuse: flat RSS (glibc)
    max_payload_bytes = 16777216         # larger payloads are refused before decoding (16 MiB)
    max_channels = 64                    # inputs + outputs of one batch
    max_identification_bytes = 536870912 # a stream's buffers + one identification (512 MiB)
    max_identification_s = 60.0          # one identification's own time; then stopped, counted
    stream_idle_s = 60.0                 # a discovered stream without a valid sample this long gives its slot back
    max_batches_per_s = 5000             # intake budget shared fairly by the streams sending (see below)
    share = true                         # divide discovered streams with the other daemons on the network
    claim_settle_s = 0.3                 # a claim on a stream stands unbeaten this long before the stream is served
    join_after_s = 10.0                  # a new daemon buffers the streams it will take this long, then joins

    [defaults]                # per-stream settings applied to every stream
    window_s = 10.0
    update_every_s = 1.0
    max_pending_windows = 1000  # closed windows that may wait for identification (1: only the newest)
    max_pending_s = 120.0     # a live stream's waiting windows: at most this much stream time behind the newest

    [streams.bench1]          # overrides for one stream
    window_s = 0.5
    cold_generations = 200
    outputs = ["force"]

    [streams.bench1.engine]   # any other CoEAConfig field (de_f, centre_bounds, ...)
    de_f = 0.5

    [streams.arm.ros2]        # the stream's fields from ROS 2 topics (streamid.daemon.ros2_config)
    inputs = ["/cmd_vel:linear.x"]
    output = "/joint_states:velocity[2]"

Unknown keys and wrong types are refused when the file is loaded, with a
:class:`~streamid.errors.ConfigError` naming the key, the accepted form and the
value found.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from streamid.daemon.ros2_config import Ros2Source, ros2_from_table, ros2_toml
from streamid.engine.settings import RETIRED_FIELDS, CoEAConfig, retired_message
from streamid.online.refresh_policy import RefreshPolicy
from streamid.online.stream_config import ENGINE_RESERVED, StreamConfig
from streamid.errors import ConfigError
from streamid.wire.keys import STREAM_NAME_RULE, is_valid_stream_name

__all__ = ["StreamConfig", "DaemonConfig", "load_config", "config_from_mapping", "stream_table_config", "to_toml"]

@dataclass(frozen=True)
class DaemonConfig:
    """The daemon's configuration.

    Attributes
    ----------
    streams
        Streams to serve from the start.
    discover
        Also serve streams found on ``streamid/*/samples`` (and ``u``/``y``).
    max_streams
        Discovered streams beyond this are refused (counted), bounding memory.
    status_every_s
        Period of the status messages.
    workers
        Identification worker threads (default 2: while one runs a coevolution, the other refreshes other
        streams' champions, numpy and the compiled loops releasing the GIL; 40 simulated 2 kHz streams decided
        at least 64 windows each in 75 s with 2, 34 with 1, docs/benchmarks.md).
    helper
        Give every worker an :class:`~streamid.engine.search.parallel.EvalHelper`: a
        process that evaluates half of each population batch on an otherwise
        idle core (same results; a warm piezo update ~1.5x faster). Ignored
        where the helper is not supported.
    retain_memory
        Let the C allocator keep and reuse freed working memory (one arena,
        fixed thresholds; see :mod:`streamid.daemon.memory`), so the resident
        set stays flat instead of swinging with every identification.
        Process-wide; applied at start.
    max_payload_bytes
        Payloads larger than this are refused before they are decoded (counted
        as ``bad.too_large`` on the stream, or ``payloads_too_large`` on the
        daemon when the stream is not served).
    max_channels
        Inputs plus outputs one batch may carry; more is refused
        (``bad.too_many_channels``).
    max_identification_bytes
        Bound of one stream's buffers plus one identification's working memory
        (:func:`streamid.daemon.admission.stream_bytes`); a batch whose window
        would need more is refused (``bad.too_large_window``).
    max_identification_s
        An identification that runs longer than this (its own time) is stopped,
        counted (``identification_timeouts``) and reported as a failed update.
    stream_idle_s
        A discovered stream that received no valid sample for this long gives
        its slot back (counted ``streams_released``; its state file stays).
    max_batches_per_s
        The intake budget: batches decoded per second, over all streams, while
        two or more streams send.  Each sending stream is guaranteed an equal
        share; a stream above its share when the budget is used up has its
        batches dropped before decoding, counted (``intake_dropped`` on the
        stream and the daemon): many small publishers cannot starve a healthy
        stream (:mod:`streamid.daemon.intake_budget`).
    share
        With ``discover``: divide the streams with the other sharing daemons on
        the network (:mod:`streamid.daemon.sharing`: liveliness tokens,
        rendezvous hashing, claims); each stream is served by one of them, and by
        the next when that one dies.  Every daemon claims a stream before serving
        it, sharing or not, so two daemons never publish one stream at once.
    claim_settle_s
        How long a new claim on a stream must stand unbeaten before the daemon
        serves the stream (longer than a token takes to cross the network).
    join_after_s
        A new sharing daemon buffers the streams it will own for this long before
        it announces itself (a stream it takes over then has a full window);
        default: one default window, 10 s.
    defaults
        Settings of every stream.
    overrides
        ``(stream, settings)`` pairs for streams with their own table.
    ros2
        ``(stream, source)`` pairs of the streams whose signals are ROS 2 topics (``[streams.X.ros2]``,
        :mod:`streamid.daemon.ros2_config`); each is served from the start, as if listed in ``streams``.
    """

    streams: tuple[str, ...] = ()
    discover: bool = True
    max_streams: int = 64
    status_every_s: float = 1.0
    workers: int = 2
    helper: bool = True
    retain_memory: bool = True
    max_payload_bytes: int = 16 * 2**20
    max_channels: int = 64
    max_identification_bytes: int = 512 * 2**20
    max_identification_s: float = 60.0
    stream_idle_s: float = 60.0
    max_batches_per_s: int = 5000
    share: bool = True
    claim_settle_s: float = 0.3
    join_after_s: float = 10.0
    defaults: StreamConfig = field(default_factory=StreamConfig)
    overrides: tuple[tuple[str, StreamConfig], ...] = ()
    ros2: tuple[tuple[str, Ros2Source], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "streams", tuple(dict.fromkeys((*self.streams, *(n for n, _ in self.ros2)))))
        for s in self.streams:
            if not is_valid_stream_name(s):
                raise ConfigError(f"daemon.streams entries must be stream names ({STREAM_NAME_RULE}); got {s!r}")
        if not self.streams and not self.discover:
            raise ConfigError("with daemon.discover = false, daemon.streams must name at least one stream; got none")
        if not 1 <= self.max_streams <= 100_000:
            raise ConfigError(f"daemon.max_streams must be an integer in [1, 100000]; got {self.max_streams!r}")
        if not (math.isfinite(self.status_every_s) and 0.01 <= self.status_every_s <= 3600):
            raise ConfigError(f"daemon.status_every_s must be a number of seconds in [0.01, 3600]; got {self.status_every_s!r}")
        if not 1 <= self.workers <= 64:
            raise ConfigError(f"daemon.workers must be an integer in [1, 64]; got {self.workers!r}")
        for key, (lo, hi) in _BOUNDS.items():
            v = getattr(self, key)
            whole = isinstance(v, int) or _DAEMON_KEYS[key][0] == "float"
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (whole and math.isfinite(v) and lo <= v <= hi):
                raise ConfigError(f"daemon.{key} must be {_DAEMON_KEYS[key][1]}; got {v!r}")

    def for_stream(self, stream: str) -> StreamConfig:
        """Settings of ``stream`` (its override, else the defaults)."""
        for name, cfg in self.overrides:
            if name == stream:
                return cfg
        return self.defaults

    def with_streams(self, streams: tuple[str, ...]) -> DaemonConfig:
        """Serve exactly ``streams`` (no discovery), e.g. from ``--stream``."""
        return dataclasses.replace(self, streams=tuple(dict.fromkeys(streams)), discover=False)

    def ros2_of(self, stream: str) -> Ros2Source | None:
        """Where ``stream``'s signals come from when they are ROS 2 topics (None: streamid's own keys)."""
        return dict(self.ros2).get(stream)


# ----------------------------------------------------------------------------- loading
_NUM = "a number"
_INT = "an integer"
_STREAM_KEYS: dict[str, tuple[str, str]] = {
    # name: (kind, accepted form)
    "window_s": ("float", "a number of seconds > 0"),
    "window_samples": ("int", "an integer number of samples >= 2"),
    "update_every_s": ("float", "a number of seconds > 0"),
    "update_every_samples": ("int", "an integer number of samples >= 1"),
    "validation_fraction": ("float", "a number in [0.05, 0.9]"),
    "cold_generations": ("int", "an integer >= 1"),
    "warm_generations": ("int", "an integer >= 1"),
    "neurons": ("int", "an integer >= 1"),
    "max_lag_y": ("int", "an integer >= 0"),
    "max_lag_u": ("int", "an integer >= 0"),
    "population": ("int", "an integer >= 4"),
    "seed": ("int", "an integer >= 0"),
    "inputs": ("names", "a list of signal names"),
    "outputs": ("names", "a list of signal names"),
    "output": ("str", "a signal name"),
    "min_r2_osa": ("float", "a number <= 1"),
    "min_r2_fr": ("float", "a number <= 1"),
    "max_abs_value": ("float", "a number > 0"),
    "cold_after_failures": ("int", "an integer >= 1"),
    "max_pending_windows": ("int", "an integer in [1, 1000]"),
    "max_pending_bytes": ("int", "an integer number of bytes >= 1"),
    "max_pending_s": ("float", "a number of seconds in [0, 86400]"),
    "challenger_margin": ("float", "a number in [-1, 1] (an R^2 difference)"),
    "drift_detection": ("bool", "true or false"),
    "drift_generations": ("int", "an integer >= 1"),
    "engine": ("table", "a table of CoEAConfig fields"),
    "refresh": ("table", "a table of RefreshPolicy fields (enabled, min_every, max_every, memory_s, ridge)"),
}
_DAEMON_KEYS: dict[str, tuple[str, str]] = {
    "streams": ("names", "a list of stream names"),
    "discover": ("bool", "true or false"),
    "max_streams": ("int", "an integer in [1, 100000]"),
    "status_every_s": ("float", "a number of seconds in [0.01, 3600]"),
    "workers": ("int", "an integer in [1, 64]"),
    "helper": ("bool", "true or false"),
    "retain_memory": ("bool", "true or false"),
    "max_payload_bytes": ("int", "an integer number of bytes in [1024, 2147483648]"),
    "max_channels": ("int", "an integer in [2, 100000]"),
    "max_identification_bytes": ("int", "an integer number of bytes in [1048576, 1099511627776]"),
    "max_identification_s": ("float", "a number of seconds in [0.1, 86400]"),
    "stream_idle_s": ("float", "a number of seconds in [0.5, 31536000]"),
    "max_batches_per_s": ("int", "an integer number of batches per second in [10, 100000000]"),
    "share": ("bool", "true or false"),
    "claim_settle_s": ("float", "a number of seconds in [0.01, 60]"),
    "join_after_s": ("float", "a number of seconds in [0, 3600]"),
}
#: Ranges of the [daemon] bounds (inclusive), as in the accepted forms above.
_BOUNDS: dict[str, tuple[float, float]] = {
    "max_payload_bytes": (1024, 2**31),
    "max_channels": (2, 100_000),
    "max_identification_bytes": (2**20, 2**40),
    "max_identification_s": (0.1, 86400.0),
    "stream_idle_s": (0.5, 365 * 86400.0),
    "max_batches_per_s": (10, 100_000_000),
    "claim_settle_s": (0.01, 60.0),
    "join_after_s": (0.0, 3600.0),
}
_TOP_KEYS = ("daemon", "defaults", "streams")


def _typed(where: str, key: str, value: Any, kind: str, form: str) -> Any:
    path = f"{where}.{key}" if where else key
    bad = ConfigError(f"{path} must be {form}; got {value!r} ({type(value).__name__})")
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise bad
        return float(value)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise bad
        return value
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise bad
        return value
    if kind == "names":
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise bad
        return tuple(value)
    if kind == "table":
        if not isinstance(value, dict):
            raise bad
        return value
    raise AssertionError(kind)  # pragma: no cover


def _unknown(where: str, table: Mapping[str, Any], accepted: Any) -> None:
    extra = [k for k in table if k not in accepted]
    if extra:
        path = f"{where}.{extra[0]}" if where else extra[0]
        raise ConfigError(f"unknown key {path!r}; accepted keys in [{where or 'top level'}]: {', '.join(sorted(accepted))}")


def stream_table_config(where: str, table: Any, base: StreamConfig) -> StreamConfig:
    """``base`` with a ``[where]`` table of stream settings applied, checked as the daemon's configuration file is
    (unknown or retired keys refused naming them; ``engine`` and ``refresh`` merged over ``base``'s)."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{where}] must be a table of stream settings; got {table!r}")
    _unknown(where, table, _STREAM_KEYS)
    kw: dict[str, Any] = {}
    for key, value in table.items():
        kind, form = _STREAM_KEYS[key]
        kw[key] = _typed(where, key, value, kind, form)
    if "engine" in kw:
        eng = kw["engine"]
        accepted = [f.name for f in fields(CoEAConfig) if f.name not in ENGINE_RESERVED]
        retired = sorted(set(eng) & set(RETIRED_FIELDS))
        if retired:
            raise ConfigError(f"[{where}.engine]: {retired_message(retired)}; accepted keys: {', '.join(sorted(accepted))}")
        _unknown(f"{where}.engine", eng, accepted)
        merged = dict(base.engine)
        for k, v in eng.items():
            merged[k] = tuple(v) if isinstance(v, list) else v
        kw["engine"] = tuple(sorted(merged.items()))
    if "refresh" in kw:  # a table of RefreshPolicy fields over the inherited policy's
        ref = kw["refresh"]
        _unknown(f"{where}.refresh", ref, [f.name for f in fields(RefreshPolicy)])
        try:
            kw["refresh"] = dataclasses.replace(base.refresh, **ref)
        except ConfigError as exc:
            raise ConfigError(f"[{where}.refresh]: {exc}") from exc
    # seconds and samples exclude each other: a table giving one clears the inherited other
    for a, b in (("window_s", "window_samples"), ("update_every_s", "update_every_samples")):
        if a in kw and b not in kw:
            kw[b] = None
        if b in kw and a not in kw:
            kw[a] = None
    try:
        return dataclasses.replace(base, **kw)
    except ConfigError as exc:
        raise ConfigError(f"[{where}]: {exc}") from exc
    except TypeError as exc:  # pragma: no cover - guarded by _STREAM_KEYS
        raise ConfigError(f"[{where}]: {exc}") from exc


def config_from_mapping(data: Mapping[str, Any], source: str = "<config>") -> DaemonConfig:
    """Build a :class:`DaemonConfig` from parsed TOML (``source`` names it in errors)."""
    try:
        return _from_mapping(data)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _from_mapping(data: Mapping[str, Any]) -> DaemonConfig:
    _unknown("", data, _TOP_KEYS)
    defaults = StreamConfig()
    if "defaults" in data:
        defaults = stream_table_config("defaults", data["defaults"], defaults)
    overrides: list[tuple[str, StreamConfig]] = []
    ros2: list[tuple[str, Ros2Source]] = []
    streams_tab = data.get("streams", {})
    if not isinstance(streams_tab, dict):
        raise ConfigError(f"[streams] must be a table of [streams.NAME] tables; got {streams_tab!r}")
    for name, tab in streams_tab.items():
        if not is_valid_stream_name(name):
            raise ConfigError(f"[streams.{name}]: the table name must be a stream name ({STREAM_NAME_RULE})")
        if isinstance(tab, dict) and "ros2" in tab:
            tab = dict(tab)
            ros2.append((name, ros2_from_table(f"streams.{name}.ros2", tab.pop("ros2"))))
        overrides.append((name, stream_table_config(f"streams.{name}", tab, defaults)))
    dkw: dict[str, Any] = {}
    dtab = data.get("daemon", {})
    if not isinstance(dtab, dict):
        raise ConfigError(f"[daemon] must be a table; got {dtab!r}")
    _unknown("daemon", dtab, _DAEMON_KEYS)
    for key, value in dtab.items():
        kind, form = _DAEMON_KEYS[key]
        dkw[key] = _typed("daemon", key, value, kind, form)
    streams = tuple(dict.fromkeys(dkw.pop("streams", ())))
    if "discover" not in dkw:
        dkw["discover"] = not streams and not ros2  # a ROS 2 stream counts as listed
    return DaemonConfig(streams=streams, defaults=defaults, overrides=tuple(overrides), ros2=tuple(ros2), **dkw)


def load_config(path: str | Path | None) -> DaemonConfig:
    """Load a TOML configuration file (None: the embedded defaults).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not TOML, or holds an unknown key or a
        value of the wrong type or range (the message names it).
    """
    if path is None:
        return DaemonConfig()
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"config file must be a readable UTF-8 TOML file; got {str(p)!r} ({exc})") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from exc
    return config_from_mapping(data, str(p))


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for these names
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def _stream_table(cfg: StreamConfig) -> tuple[dict[str, Any], dict[str, Any]]:
    """Every effective setting of a stream, and its effective engine settings (the ``engine`` table)."""
    plain = cfg.to_dict()
    plain.pop("engine", None)
    plain.pop("refresh", None)
    if cfg.window_s is None and cfg.window_samples is None:
        plain["window_s"] = cfg.window_params().window_s
    if cfg.update_every_s is None and cfg.update_every_samples is None:
        plain["update_every_s"] = cfg.window_params().hop_s
    order = [f.name for f in fields(StreamConfig)]
    plain = {k: plain[k] for k in sorted(plain, key=order.index)}
    engine = cfg.coea_config(cold=True).to_dict()
    if "search_rows" not in dict(cfg.engine):  # online it is the search's row bound (streamid.online.rows), whose
        del engine["search_rows"]  # default depends on the inputs the data bring: printed, 0 would mean every row
    return plain, {k: v for k, v in engine.items() if k not in ENGINE_RESERVED and v is not None}


def to_toml(config: DaemonConfig) -> str:
    """Every effective setting as a TOML file that :func:`load_config` reads back to the same configuration."""
    lines = ["# streamid daemon: every effective setting (paste into a --config file)", "", "[daemon]"]
    for f in fields(DaemonConfig):
        if f.name not in ("defaults", "overrides", "ros2"):
            lines.append(f"{f.name} = {_toml_value(getattr(config, f.name))}")
    tables = [("defaults", config.defaults), *((f"streams.{n}", c) for n, c in config.overrides)]
    for name, cfg in tables:
        plain, engine = _stream_table(cfg)
        lines += ["", f"[{name}]", *(f"{k} = {_toml_value(v)}" for k, v in plain.items())]
        lines += ["", f"[{name}.engine]", *(f"{k} = {_toml_value(v)}" for k, v in engine.items())]
        if "search_rows" not in engine:
            lines.append("# search_rows: the default bound, max(4096, 128 (neurons + D + 1)) rows, "
                         "D = max_lag_y + inputs x max_lag_u (0: every row)")
        lines += ["", f"[{name}.refresh]", *(f"{k} = {_toml_value(v)}" for k, v in cfg.refresh.to_dict().items())]
        if (src := config.ros2_of(name.removeprefix("streams."))) is not None and name.startswith("streams."):
            lines += ["", *ros2_toml(f"{name}.ros2", src)]
    return "\n".join(lines) + "\n"
