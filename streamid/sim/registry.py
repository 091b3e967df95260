"""The registry of simulated devices: each device's simulator, timing, channel names and units (``get_device``)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from streamid.errors import ConfigError
from streamid.sim._common import Trace, as_generator
from streamid.sim.boucwen import BENCHMARK_PERIOD_NS, simulate_bouc_wen_multisine
from streamid.sim.mrdamper import MRDamperParams, simulate_mr_damper
from streamid.sim.piezo import PiezoParams, simulate_piezo
from streamid.sim.reactor import ReactorParams, simulate_reactor

__all__ = ["ALIASES", "DEVICES", "Device", "Simulator", "device_names", "get_device"]

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
