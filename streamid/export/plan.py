"""What an export holds: the models (one per output), their networks, names and sample period, checked.

:func:`plan_of` turns one or more models (one per modelled output, all of the same inputs) into an
:class:`ExportPlan`, refusing anything the generated code could not reproduce exactly. The code generators
(:mod:`streamid.export.ccode`, :mod:`streamid.export.fmu`) only read the plan.

The timing convention (the same in the C step function, the FMU and :meth:`Model.simulate
<streamid.model.narx.Model.simulate>`): sample ``k`` (``k = 0, 1, ...`` from the start) is computed from the
inputs of samples ``0 .. k`` (sample ``k``'s own only through a direct term, an input at lag 0) and the
outputs of samples ``0 .. k-1``; the first ``max_lag`` outputs of a model are its initial value (the model's
initial history, ``y_init`` of ``Model.simulate``), and each member of an ensemble starts predicting at its
own ``max_lag`` from that same history, as ``Model.simulate`` does.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from streamid.model.ensemble import members_of
from streamid.model.narx import Model
from streamid.model.regressors import Regressor
from streamid.model.uncertainty import DEFAULT_LEVEL
from streamid.errors import ConfigError, ModelFormatError
from streamid.wire.names import check_signal_names, printable

__all__ = ["BAND_LEVEL", "CONVENTION", "ExportPlan", "Network", "Output", "c_identifier", "model_period_s", "plan_of"]

#: The level of the band an export's ``<output>_lower`` / ``<output>_upper`` give (the reported one).
BAND_LEVEL = DEFAULT_LEVEL

#: The timing convention in words (the C header, the FMU's description and docs/export.md say it).
CONVENTION = (
    "Sample k (k = 0, 1, ... from the start, one sample period apart) of every output is computed from the "
    "inputs of samples 0..k (sample k's own input only through a direct term, an input at lag 0) and the "
    "outputs of samples 0..k-1. The first max_lag samples of an output are its initial value (the model's "
    "initial history, Model.simulate's y_init; each member of an ensemble starts at its own max_lag), so a "
    "run equals Model.simulate(u, [initial] * max_lag) at every sample."
)

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def c_identifier(text: str) -> str:
    """``text`` made a C identifier (other characters become ``_``; a leading digit gets ``m_``)."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", text) or "model"
    return ident if not ident[0].isdigit() else f"m_{ident}"


@dataclass(frozen=True)
class Network:
    """One RBF network (a model, or a member of an ensemble) of one output, in normalised units."""

    regressors: tuple[Regressor, ...]
    centres: tuple[tuple[float, ...], ...]
    two_w2: tuple[float, ...]  # 2 widths^2, per neuron
    weights: tuple[float, ...]
    linear: tuple[float, ...] | None  # coefficients, then the constant
    linear_regressors: tuple[Regressor, ...]  # the linear part's (the network's own when it has none of its own)
    max_lag: int


@dataclass(frozen=True)
class Output:
    """One modelled output: its name, normalisation and networks (several: an ensemble, their mean or their
    per-sample median), its band (``q`` and ``scale`` of the model's 90 % interval, None without one) and the
    regressors whose estimation ranges its ``<output>_in_domain`` checks (every member's, each once)."""

    name: str
    y_low: float
    y_high: float
    u_low: tuple[float, ...]
    u_high: tuple[float, ...]
    networks: tuple[Network, ...]
    max_lag: int
    direct_inputs: tuple[int, ...]  # inputs used at lag 0 (direct terms), in input order
    combine: str = "mean"  # "mean" | "median" of the networks' outputs
    # (q at BAND_LEVEL, scale, beyond): centre -+ q (scale + members' std + beyond * excess * y half-range)
    band: tuple[float, float, float] | None = None
    domain: tuple[Regressor, ...] = ()  # the union of the networks' regressors (and linear parts')

    @property
    def extras(self) -> tuple[str, ...]:
        """The names of the output's added variables, in order: ``<output>_lower``, ``<output>_upper`` (with a
        band) and ``<output>_in_domain``."""
        band = (f"{self.name}_lower", f"{self.name}_upper") if self.band is not None else ()
        return (*band, f"{self.name}_in_domain")

    @property
    def middle(self) -> float:
        """The middle of the output's range: the default initial value (halves first: never overflows)."""
        return 0.5 * self.y_low + 0.5 * self.y_high


@dataclass(frozen=True)
class ExportPlan:
    """Everything the generated code holds (see :func:`plan_of`)."""

    name: str  # the C prefix and FMU model identifier
    inputs: tuple[str, ...]
    outputs: tuple[Output, ...]
    period_s: float
    description: str

    @property
    def history(self) -> int:
        """Samples every ring buffer holds: the largest lag + 1 (the current sample)."""
        return max(o.max_lag for o in self.outputs) + 1

    @property
    def extras(self) -> tuple[tuple[int, str], ...]:
        """Every added output variable (band and domain) with its output's index, in output order."""
        return tuple((i, name) for i, o in enumerate(self.outputs) for name in o.extras)

    @property
    def networks(self) -> tuple[tuple[int, Network], ...]:
        """Every network with its output's index, in output order."""
        return tuple((i, n) for i, o in enumerate(self.outputs) for n in o.networks)


def model_period_s(model: Model) -> float | None:
    """The sample period the model was identified at (from its window: ``period_ns``, or its times), or None."""
    w = model.window
    period = w.get("period_ns")
    if isinstance(period, int) and not isinstance(period, bool) and period > 0:
        return period / 1e9
    t0, t1, n = w.get("t0_ns"), w.get("t1_ns"), w.get("n_samples")
    if isinstance(t0, int) and isinstance(t1, int) and isinstance(n, int) and n >= 2 and t1 > t0:
        return round((t1 - t0) / (n - 1)) / 1e9
    return None


def _finite(values: tuple[float, ...], what: str, output: str) -> tuple[float, ...]:
    """``values``, refused (ModelFormatError naming the output, the field and the index) if one is not finite."""
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise ModelFormatError(f"model of '{printable(output, 120)}': {what}[{i}] is {v!r}, which C cannot "
                                   "spell (finite float64 numbers only, |x| < 1.8e308): the model cannot be exported")
    return values


def _network(m: Model, output: str) -> Network:
    lin = None if m.linear is None else _finite(tuple(float(v) for v in m.linear), "linear", output)
    lregs = m.regressors if m.linear_regressors is None else m.linear_regressors
    return Network(
        regressors=m.regressors,
        centres=tuple(_finite(tuple(float(v) for v in row), f"centres[{j}]", output) for j, row in enumerate(m.centres)),
        two_w2=_finite(tuple(2.0 * (float(v) * float(v)) for v in m.widths), "2 widths^2 (the generated code's two_w2)", output),
        weights=_finite(tuple(float(v) for v in m.weights), "weights", output),
        linear=lin,
        linear_regressors=lregs if lin is not None else (),
        max_lag=m.max_lag,
    )


def _spellable(o: Output) -> None:
    """Refuse an output whose derived constants (range, middle, input middles) overflow to infinity."""
    _finite((o.y_low, o.y_high, o.middle, o.y_high - o.y_low), "y_low, y_high, middle, span", o.name)
    _finite(tuple(0.5 * lo + 0.5 * hi for lo, hi in zip(o.u_low, o.u_high)), "input middles", o.name)


def _band(m: Model) -> tuple[float, float, float] | None:
    """``(q, scale, beyond)`` of the model's interval at :data:`BAND_LEVEL`; None when it carries none."""
    if m.interval is None:
        return None
    if not any(abs(lv - BAND_LEVEL) < 1e-12 for lv in m.interval.levels):
        raise ModelFormatError(f"model of '{printable(m.output_name, 120)}': its interval has no level {BAND_LEVEL:g} "
                               f"(levels {', '.join(f'{v:g}' for v in m.interval.levels)}); the export's "
                               f"<output>_lower and <output>_upper are the {100 * BAND_LEVEL:g} % band")
    q, scale = m.interval.quantile(BAND_LEVEL), m.interval.scale
    _finite((q, scale, q * scale, m.interval.beyond), "interval quantile, scale, beyond", m.output_name)
    return q, scale, m.interval.beyond


def plan_of(models: Sequence[Model], name: str, period_s: float | None = None) -> ExportPlan:
    """The export of ``models`` (one per output, the same inputs in the same order) under the C name ``name``.

    ``period_s``: the sample period in seconds; None: the models' own (their windows must record one, the same).

    Raises
    ------
    ConfigError
        No model, two of one output, inputs that differ, no or differing sample periods, a bad name.
    ModelFormatError
        A model the generated code cannot reproduce (a normalisation of zero span, a non-finite number).
    """
    if not models:
        raise ConfigError("an export needs at least one model file (one per output)")
    if not _IDENT.match(name):
        raise ConfigError(f"the export's name must be a C identifier ([A-Za-z_][A-Za-z0-9_]*); got {name!r}")
    inputs = tuple(models[0].input_names)
    outputs: list[Output] = []
    for m in models:
        if tuple(m.input_names) != inputs:
            raise ConfigError(printable(f"every model of an export must take the same inputs in the same order: "
                                        f"{m.output_name!r} takes {list(m.input_names)}, {models[0].output_name!r} "
                                        f"{list(inputs)}", 600))
        if any(o.name == m.output_name for o in outputs):
            raise ConfigError(f"two models of output '{printable(m.output_name, 120)}': give one model file per output")
        nm = m.normalisation
        spans = [nm.y_high - nm.y_low, *(h - lo for lo, h in zip(nm.u_low, nm.u_high))]
        if not all(math.isfinite(s) and s > 0 for s in spans):
            raise ModelFormatError(f"model of '{printable(m.output_name, 120)}': its normalisation must have finite "
                                   f"ranges high > low; got {nm.to_dict()}")
        nets = tuple(_network(member, m.output_name) for member in members_of(m))
        direct = sorted({r.index for member in members_of(m)
                         for r in (*member.regressors, *(member.linear_regressors or ())) if r.signal == "u" and r.lag == 0})
        outputs.append(Output(name=m.output_name, y_low=float(nm.y_low), y_high=float(nm.y_high),
                              u_low=tuple(float(v) for v in nm.u_low), u_high=tuple(float(v) for v in nm.u_high),
                              networks=nets, max_lag=m.max_lag, direct_inputs=tuple(direct),
                              combine=str(getattr(m, "combine", "mean")), band=_band(m),
                              domain=tuple(sorted({r for member in members_of(m)
                                                   for r in (*member.regressors, *(member.linear_regressors or ()))},
                                                  key=lambda r: (r.signal, r.index, r.lag)))))
        _spellable(outputs[-1])
    # the one rule for names (streamid.wire.names) over the whole export: every output's name distinct from every
    # input's and every other output's, and from the names streamid adds for each (initial_<output>, ...)
    check_signal_names(inputs, [o.name for o in outputs], "export")
    if period_s is None:
        periods = {model_period_s(m) for m in models}
        if None in periods:
            bad = next(m.output_name for m in models if model_period_s(m) is None)
            raise ConfigError(f"the model of '{printable(bad, 120)}' records no sample period (its window has no period_ns): "
                              "give it with --period SECONDS")
        if len(periods) > 1:
            raise ConfigError(f"the models were identified at different sample periods {sorted(p or 0 for p in periods)} s: "
                              "export models of one stream together")
        period_s = periods.pop()
    if period_s is None or not (math.isfinite(period_s) and period_s > 0):
        raise ConfigError(f"the sample period must be a number of seconds > 0; got {period_s!r}")
    text = "; ".join(f"{o.name} = F({', '.join(inputs)}, past {o.name})" for o in outputs)
    return ExportPlan(name=name, inputs=inputs, outputs=tuple(outputs), period_s=float(period_s),
                      description=f"streamid RBF-NARX model: {text}")
