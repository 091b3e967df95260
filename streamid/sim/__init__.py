"""Simulated devices: pure numpy/scipy, seeded, with their physics documented per module.

==========  =======  ===============================================  ==================================
device      rate     model (module)                                   input -> output
==========  =======  ===============================================  ==================================
piezo       20 kHz   Bouc-Wen hysteresis + 1 kHz bending mode          voltage_V -> deflection_um
                     + 5 kHz / 40 nm sensor (:mod:`.piezo`)
mr_damper   200 Hz   Spencer et al. 1997 phenomenological model        velocity_cm_s -> force_N
                     (:mod:`.mrdamper`)
reactor     5 Hz     MMA polymerization reactor, paper eq. 17          initiator_flow -> molecular_weight
                     (:mod:`.reactor`)
bouc_wen    750 Hz   Bouc-Wen benchmark oscillator, multisine          force_N -> displacement_m
                     (:mod:`.boucwen`)
==========  =======  ===============================================  ==================================

Every simulator has the signature ``f(n_samples, rng) -> Trace`` (``rng`` a
:class:`numpy.random.Generator` or an integer seed) and returns
``Trace(t_ns, u, y)``: int64 sample times from 0 in steps of the device's
``period_ns``, the input and the output. The global numpy RNG is never used.

:func:`simulate_drift` (:mod:`.drift`) simulates the damper or the piezo with
its output-level parameters changed by a given fraction at a given time
(:data:`DRIFTS` says which), for testing drift detection.

This registry is the only list of devices: ``streamid simulate`` (the
``recorders`` package) writes the log of every device that has a ``stream``,
in batches of ``batch_size`` samples.

Examples
--------
>>> from streamid.sim import get_device
>>> dev = get_device("reactor")
>>> t_ns, u, y = dev.simulate_seconds(10.0, seed=1)
>>> len(y), dev.period_ns
(50, 200000000)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from streamid.errors import ConfigError
from streamid.sim._common import Trace, as_generator
from streamid.sim.boucwen import (
    BENCHMARK_PERIOD_NS,
    BoucWenParams,
    bouc_wen_operator,
    integrate_bouc_wen,
    simulate_bouc_wen,
    simulate_bouc_wen_multisine,
    simulate_bouc_wen_periodic,
)
from streamid.sim.drift import DRIFTS, DriftSpec, drift_start_ns, simulate_drift
from streamid.sim.mrdamper import MRDamperParams, simulate_mr_damper
from streamid.sim.piezo import PiezoParams, piezo_excitation, simulate_piezo, simulate_piezo_input
from streamid.sim.reactor import (
    ReactorParams,
    reactor_steady_state,
    simulate_reactor,
    simulate_reactor_input,
)

__all__ = [
    "ALIASES",
    "BENCHMARK_PERIOD_NS",
    "DEVICES",
    "DRIFTS",
    "BoucWenParams",
    "Device",
    "DriftSpec",
    "MRDamperParams",
    "PiezoParams",
    "ReactorParams",
    "Trace",
    "bouc_wen_operator",
    "device_names",
    "drift_start_ns",
    "get_device",
    "integrate_bouc_wen",
    "piezo_excitation",
    "reactor_steady_state",
    "simulate_bouc_wen",
    "simulate_bouc_wen_multisine",
    "simulate_bouc_wen_periodic",
    "simulate_drift",
    "simulate_mr_damper",
    "simulate_piezo",
    "simulate_piezo_input",
    "simulate_reactor",
    "simulate_reactor_input",
]

Simulator = Callable[[int, "np.random.Generator | int"], Trace]


@dataclass(frozen=True)
class Device:
    """A simulated device: its simulator, timing and channel names/units.

    Attributes
    ----------
    name : str
        Registry name.
    simulate : callable
        ``simulate(n_samples, rng) -> Trace``.
    period_ns : int
        Sample period in ns.
    input_name, input_unit : str
        Name (unit in the name) and unit of the single input channel.
    output_name, output_unit : str
        Same for the single output channel.
    default_seconds : float
        A sensible record length.
    min_seconds : float
        Shortest record the excitation supports (its lowest frequency line needs it).
    description : str
        One line on the model (also the ``model`` of a simulated log's metadata).
    stream : str or None
        Stream a simulated recorder of the device publishes on
        (``streamid simulate``); None: the device has no recorder.
    batch_size : int
        Samples per published batch of that recorder.
    """

    name: str
    simulate: Simulator
    period_ns: int
    input_name: str
    input_unit: str
    output_name: str
    output_unit: str
    default_seconds: float
    min_seconds: float
    description: str
    stream: str | None = None
    batch_size: int = 1

    @property
    def rate_hz(self) -> float:
        """Sample rate in Hz."""
        return 1e9 / self.period_ns

    def n_samples(self, seconds: float) -> int:
        """Samples in ``seconds`` of record (rounded), validated against ``min_seconds``."""
        try:
            s = float(seconds)
        except (TypeError, ValueError):
            s = math.nan
        if not (math.isfinite(s) and s >= self.min_seconds):
            raise ConfigError(
                f"the {self.name} record must last at least {self.min_seconds:g} s (finite); got {seconds!r}"
            )
        return max(1, int(round(s * 1e9 / self.period_ns)))

    def simulate_seconds(self, seconds: float, seed: int | np.random.Generator) -> Trace:
        """Simulate ``seconds`` of record with a seed (or Generator)."""
        return self.simulate(self.n_samples(seconds), as_generator(seed))


def _bouc_wen_device(n_samples: int, rng: np.random.Generator | int) -> Trace:
    return simulate_bouc_wen_multisine(n_samples, rng)


_DEVICES = {
    d.name: d
    for d in (
        Device(
            "piezo", simulate_piezo, PiezoParams().period_ns, "voltage_V", "V", "deflection_um", "um",
            10.0, 0.05,
            "PZT/Cu unimorph micromanipulator: Bouc-Wen hysteresis, 1 kHz bending mode, 5 kHz/40 nm sensor",
            stream="piezo", batch_size=200,  # 10 ms per batch
        ),
        Device(
            "mr_damper", simulate_mr_damper, MRDamperParams().period_ns, "velocity_cm_s", "cm/s",
            "force_N", "N", 60.0, 0.1,
            "MR damper, Spencer et al. 1997 phenomenological model, band-limited random velocity",
            stream="mr_damper_sim", batch_size=20,  # 100 ms per batch
        ),
        Device(
            "reactor", simulate_reactor, ReactorParams().period_ns, "initiator_flow", "1",
            "molecular_weight", "g/mol", 192.0, 0.2,
            "continuous MMA polymerization reactor of the paper (eq. 17), u ~ U[0.007, 0.015]",
            stream="reactor", batch_size=5,  # 1 s per batch
        ),
        Device(
            "bouc_wen", _bouc_wen_device, BENCHMARK_PERIOD_NS, "force_N", "N", "displacement_m", "m",
            60.0, 0.2,
            "Bouc-Wen benchmark oscillator (Noel & Schoukens 2016), 5-150 Hz random-phase multisine, 50 N RMS",
        ),
    )
}

#: Registry of devices by name (read-only).
DEVICES: Mapping[str, Device] = MappingProxyType(_DEVICES)

#: Accepted alternative spellings.
ALIASES: Mapping[str, str] = MappingProxyType(
    {"mrdamper": "mr_damper", "mr-damper": "mr_damper", "boucwen": "bouc_wen", "bouc-wen": "bouc_wen"}
)


def device_names() -> tuple[str, ...]:
    """Registered device names."""
    return tuple(DEVICES)


def get_device(name: str) -> Device:
    """Look a device up by name or alias.

    Raises
    ------
    ConfigError
        If the name is unknown (the message lists the accepted names).
    """
    key = ALIASES.get(name, name) if isinstance(name, str) else name
    if key not in DEVICES:
        raise ConfigError(f"device must be one of {', '.join(DEVICES)} (or {', '.join(ALIASES)}); got {name!r}")
    return DEVICES[key]
