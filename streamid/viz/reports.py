"""Plain data of the Rerun diagnostics: sink settings and what one update draws.

No ``rerun`` import here (:mod:`streamid.viz.rerun_view` is the only module that imports
it), so the daemon can build reports and check settings without it.
"""

from __future__ import annotations

import dataclasses
import math
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from streamid.model.regressors import format_lags
from streamid.engine.validation import TESTS, CorrelationTest
from streamid.errors import ConfigError

__all__ = [
    "LAYOUTS",
    "VizSettings",
    "UpdateReport",
    "parse_rerun_url",
    "first_input_tests",
    "model_markdown",
    "run_text",
    "fmt_metric",
    "TEST_LABELS",
    "SERIES_STYLES",
    "band_of",
    "band_text",
]

#: The five residual correlation tests (Billings & Voon): the engine's names and formulas (``ee: φ_ee(τ) = δ(τ)``).
TEST_LABELS = {name: f"{name}: {formula}" for name, (formula, _) in TESTS.items()}

#: Colour and legend name of each time series under ``streams/<stream>/`` (sent once per stream and file, static).
SERIES_STYLES: dict[str, tuple[tuple[int, int, int], str]] = {
    "validation/measured": ((230, 230, 230), "measured"),
    "validation/osa": ((66, 150, 250), "one step ahead"),
    "validation/free_run": ((250, 140, 40), "free run"),
    "validation/lower": ((200, 150, 100), "free run's band, lower"),
    "validation/upper": ((200, 150, 100), "free run's band, upper"),
    "residual/osa": ((66, 150, 250), "one step ahead"),
    "residual/free_run": ((250, 140, 40), "free run"),
    "history/r2_osa": ((66, 150, 250), "one step ahead, when it won"),
    "history/r2_fr": ((250, 140, 40), "free run, when it won"),
    "history/champion_r2_fr": ((250, 200, 120), "champion's free run, re-validated"),
    "history/rejected_r2_fr": ((220, 60, 60), "rejected challenger's free run"),
    "history/identification_s": ((120, 200, 120), "identification time [s]"),
    "history/latency_s": ((200, 120, 200), "window closed -> model published [s]"),
}


def parse_rerun_url(url: str) -> tuple[str, int]:
    """Host and port of a ``rerun+http://HOST:PORT/proxy`` URL (for the reachability probe)."""
    p = urllib.parse.urlparse(url)
    if p.scheme not in ("rerun", "rerun+http", "rerun+https") or not p.hostname or p.path != "/proxy":
        raise ConfigError(
            f"--rerun-connect must be a URL like rerun+http://127.0.0.1:9876/proxy "
            f"(scheme rerun, rerun+http or rerun+https, path /proxy); got {url!r}"
        )
    try:
        port = p.port or (443 if p.scheme == "rerun+https" else 9876)
    except ValueError as exc:
        raise ConfigError(f"--rerun-connect port must be an integer 1-65535; got {url!r}") from exc
    return p.hostname, port


#: The layouts of :class:`VizSettings`: the daemon's, one offline identification's, one model judged on a record.
LAYOUTS = ("daemon", "identify", "validate")


@dataclass(frozen=True)
class VizSettings:
    """Where the diagnostics go.

    Attributes
    ----------
    rrd
        Path of an ``.rrd`` file to write (None: no file).
    connect
        URL of a running viewer (``rerun+http://127.0.0.1:9876/proxy``).
    serve_port
        Serve a gRPC endpoint on 127.0.0.1:PORT for viewers to connect to.
    serve_bind
        Address the served endpoint binds (loopback unless configured).
    serve_memory_limit
        Memory the served endpoint keeps for late viewers (oldest dropped).
    probe_every_s
        How often the viewer link of ``connect`` is checked.
    application_id, recording_id
        Rerun identifiers.
    rrd_rotate_mb, rrd_rotate_s
        Close the ``.rrd`` (footer written) and continue in ``<stem>.001.rrd``,
        ``<stem>.002.rrd``... once it passes ``rrd_rotate_mb`` or, if set, once it
        is ``rrd_rotate_s`` old and something was drawn into it (checked on
        each draw and every ``rrd_rotate_s / 2`` when idle; see
        :mod:`streamid.viz.rrd_files`).  A file sink keeps per-chunk metadata in
        memory for its footer (about a quarter of the file's size here): rotation
        bounds that memory on an endless run; rotating by time bounds what a
        SIGKILL leaves without a footer to the newest ``rrd_rotate_s`` (the
        ``streamid daemon`` command rotates every 5 s).  ``rrd_rotate_mb`` None:
        one file, never rotated (``rrd_rotate_s`` is then ignored).
    rrd_keep, rrd_max_mb
        Keep at most this many segments and this many MB in all (default 4096
        segments, 1024 MB); the oldest are removed first and counted
        (:attr:`streamid.viz.rerun_view.Viz.file_stats`).
    max_points
        Longest series drawn per update (validation part and input-output plane
        are decimated by a stride beyond it).
    layout
        ``"daemon"`` (champions over time), ``"identify"`` (one offline identification: the kept model) or
        ``"validate"`` (a model judged on a record: no identification, so no fitness or timing views).
    """

    rrd: str | None = None
    connect: str | None = None
    serve_port: int | None = None
    serve_bind: str = "127.0.0.1"
    serve_memory_limit: str = "256MiB"
    probe_every_s: float = 2.0
    application_id: str = "streamid"
    recording_id: str | None = None
    rrd_rotate_mb: float | None = 64.0
    rrd_rotate_s: float | None = None
    rrd_keep: int = 4096
    rrd_max_mb: float | None = 1024.0
    max_points: int = 1000
    layout: str = "daemon"

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ConfigError(f"layout must be one of {LAYOUTS}; got {self.layout!r}")
        if self.connect is not None:
            parse_rerun_url(self.connect)
        if self.serve_port is not None and not (
            isinstance(self.serve_port, int) and 1 <= self.serve_port <= 65535
        ):
            raise ConfigError(f"--rerun-serve must be a TCP port 1-65535; got {self.serve_port!r}")
        if self.rrd_rotate_mb is not None and not self.rrd_rotate_mb > 0:
            raise ConfigError(f"rrd_rotate_mb must be a size in MB > 0 or None; got {self.rrd_rotate_mb!r}")
        if self.rrd_rotate_s is not None and not self.rrd_rotate_s > 0:
            raise ConfigError(f"rrd_rotate_s (--rrd-rotate-s) must be a number of seconds > 0 or None; "
                              f"got {self.rrd_rotate_s!r}")
        if self.rrd_max_mb is not None and not self.rrd_max_mb > 0:
            raise ConfigError(f"rrd_max_mb must be a size in MB > 0 or None; got {self.rrd_max_mb!r}")
        if not (isinstance(self.rrd_keep, int) and self.rrd_keep >= 1):
            raise ConfigError(f"rrd_keep must be an integer >= 1; got {self.rrd_keep!r}")
        if not (isinstance(self.max_points, int) and self.max_points >= 10):
            raise ConfigError(f"max_points must be an integer >= 10; got {self.max_points!r}")

    @property
    def enabled(self) -> bool:
        """Whether any sink is configured."""
        return self.rrd is not None or self.connect is not None or self.serve_port is not None


@dataclass(frozen=True)
class UpdateReport:
    """Everything drawn for one identification update of a stream.

    Arrays of the validation part share one length; times are
    ``val_t0_ns + i * period_ns``.
    """

    stream: str
    version: int
    accepted: bool
    warm: bool
    generations: int
    window_t0_ns: int
    window_end_ns: int
    period_ns: int
    val_t0_ns: int
    y_val: np.ndarray
    osa_val: np.ndarray
    fr_val: np.ndarray
    u_val: np.ndarray
    input_name: str
    output_name: str
    fitness: np.ndarray
    correlations: tuple[CorrelationTest, ...]
    lags: Mapping[str, Any]
    metrics: Mapping[str, float]
    identification_s: float
    latency_s: float | None = None
    note: str = ""
    input_names: tuple[str, ...] = field(default=())
    champion_r2_fr: float | None = None  # a rejected challenger's champion, re-validated on the same held-out data
    networks: int = 1  # > 1: the model combines this many networks (streamid.model/3, /6); ``lags`` is their union
    combine: str = "mean"  # how: their per-sample "mean" or "median" (issue 51: the median of the finished restarts)
    linear_parts: int = 0  # how many of its networks have a direct linear part a'r + b (CoEAConfig.linear_terms)
    long_linear_order: int = 0  # > 0: its linear part is a dense ARX part of this order (CoEAConfig.long_linear)
    judged_only: bool = False  # a model judged on a record (streamid validate): no identification ran
    refinement: Mapping[str, Any] | None = None  # the model's metrics.refinement (streamid.engine.choice.refine), if any
    refreshed_from: int | None = None  # a refresh (streamid.online.refresh): the champion's version it re-solved
    lower_val: np.ndarray | None = None  # the free run's band on the validation part (the model's interval), or None
    upper_val: np.ndarray | None = None
    band_level: float = 0.9  # the band's level


def run_text(r: UpdateReport, sep: str = " · ") -> str:
    """How the model was made, as ``streamid watch`` says it: ``refreshed from v3`` (the champion's weights
    re-solved on new data, no coevolution run) or ``warm`` / ``cold`` and the run's generations ``G=30``."""
    if r.refreshed_from is not None:
        return f"refreshed from v{r.refreshed_from}"
    return f"{'warm' if r.warm else 'cold'}{sep}G={r.generations}"


def fmt_metric(v: float | None) -> str:
    """A metric for display: 4 decimals, or n/a."""
    return "n/a" if v is None or not math.isfinite(v) else f"{v:.4f}"


def model_markdown(r: UpdateReport) -> str:
    """The newest model as Markdown: version, R², lags, and each correlation test's verdict (with the reason of a failure)."""
    lags = r.lags
    u_lags = list(lags.get("u", []))
    names = list(r.input_names or (r.input_name,))
    names += [f"u{i}" for i in range(len(names), len(u_lags))]
    m = r.metrics
    verdicts = []
    for c in r.correlations:
        if len(c.values):
            v = c.verdict()
            verdicts.append(f"- **{v}**" if not c.passed else f"- {v}")
    if r.judged_only:
        head = [f"**{r.stream}** · the model judged on this record (no identification ran)", "",
                f"R² on the record: OSA **{fmt_metric(m.get('r2_osa_val'))}** · FR **{fmt_metric(m.get('r2_fr_val'))}**"]
    else:
        head = [f"**{r.stream} v{r.version}** · {run_text(r)} · "
                f"{r.identification_s:.2f} s{'' if r.accepted else ' · **rejected**'}", "",
                f"R² validation: OSA **{fmt_metric(m.get('r2_osa_val'))}** · FR **{fmt_metric(m.get('r2_fr_val'))}** "
                f"(estimation {fmt_metric(m.get('r2_osa_est'))} · {fmt_metric(m.get('r2_fr_est'))})"]
    lines = [
        *head,
        "",
        f"model: {r.output_name}(t) = " + (f"{r.combine} of {r.networks} networks on " if r.networks > 1 else "")
        + f"F[{format_lags(r.output_name, lags.get('y', []), names, u_lags)}]"
        + (" (the union of their lags)" if r.networks > 1 else "") + _linear_text(r),
    ]
    lines += ["", band_text(r)]
    refined = refinement_text(r.refinement)
    if refined:
        lines += ["", refined]
    if verdicts:
        lines += ["", "correlation tests (validation residual):", *verdicts]
    return "\n".join(lines)


def band_text(r: UpdateReport) -> str:
    """What the model text says of the free run's band: its level and how much of the validation part it covered
    (``metrics.interval_coverage_val``), the share outside the estimation domain, or that the model has none."""
    if r.lower_val is None or r.upper_val is None:
        return "no prediction interval (the model carries none)"
    cov, out = r.metrics.get("interval_coverage_val"), r.metrics.get("outside_domain_val")
    text = f"{100 * r.band_level:g} % band around the free run"
    if cov is not None and math.isfinite(cov):
        text += f": covers **{100 * cov:.1f} %** of the validation samples"
    if out is not None and math.isfinite(out) and out > 0:
        text += f"; {100 * out:.1f} % of them outside the estimation domain"
    return text


def band_of(model: Any, u: np.ndarray, y: np.ndarray, level: float = 0.9) -> tuple[dict[str, Any], dict[str, float]]:
    """The fields of an :class:`UpdateReport` that draw ``model``'s band (of ``level``) on the validation part
    ``(u, y)``, and its coverage and the share outside the estimation domain there (``metrics`` entries); both
    empty when the model carries no interval or the part is too short. ``model`` a Model (read, not imported)."""
    from streamid.model.domain import outside_share
    from streamid.model.uncertainty import band_coverage

    L = int(model.max_lag)
    if getattr(model, "interval", None) is None or len(y) <= L:
        return {}, {}
    with np.errstate(over="ignore", invalid="ignore"):
        band = model.simulate(u, y[:L], interval=level)
    figures = {"interval_coverage_val": band_coverage(y, band, L)["coverage"],
               "outside_domain_val": outside_share(model, u, y)}
    return {"lower_val": band.lower, "upper_val": band.upper, "band_level": level}, figures


def held_out_gain(ev: Any) -> str | None:
    """``"a -> b"``, the held-out half's free-run R^2 before and after, when the refinement evidence ``ev`` (a
    model's ``metrics.refinement``, perhaps from the network) says it was made; None when it was not."""
    if not isinstance(ev, Mapping) or ev.get("taken") is not True:
        return None
    got = ev.get("held_out")
    held: Mapping[str, Any] = got if isinstance(got, Mapping) else {}
    a, b = (held.get(k) for k in ("r2_fr_before", "r2_fr_after"))
    return " -> ".join(fmt_metric(float(v)) if isinstance(v, (int, float)) and not isinstance(v, bool) else "n/a"
                       for v in (a, b))


def refinement_text(ev: Mapping[str, Any] | None) -> str:
    """What the refinement did (the model's ``metrics.refinement``; "" without one): made, with the held-out half's
    free-run R^2 that let it, or why not."""
    gain = held_out_gain(ev)
    if gain is not None:
        return f"weights refined to the free run (held-out half FR {gain})"
    reason = ev.get("reason") if isinstance(ev, Mapping) else None
    return f"weights not refined: {reason}" if isinstance(reason, str) and reason else ""


def _linear_text(r: UpdateReport) -> str:
    """What the model text adds for direct linear parts: nothing without one."""
    if not r.linear_parts:
        return ""
    if r.long_linear_order:
        each = "each network with its own" if r.networks > 1 else "a"
        return f" + {each} linear ARX part of order {r.long_linear_order} (its own lags 1..{r.long_linear_order})"
    if r.networks == 1:
        return " + a direct linear part a'r + b"
    return f"; {r.linear_parts} of the {r.networks} networks with a direct linear part a'r + b"


def first_input_tests(tests: tuple[CorrelationTest, ...]) -> tuple[CorrelationTest, ...]:
    """The correlation tests drawn (by the daemon and by ``streamid identify --rrd``): ``ee`` and those of the first input, named by their kind (``ue``, not ``ue[force]``)."""
    seen: set[str] = set()
    out = []
    for t in tests:
        kind = t.name.split("[", 1)[0]
        if kind not in seen:
            seen.add(kind)
            out.append(t if kind == t.name else dataclasses.replace(t, name=kind))
    return tuple(out)
