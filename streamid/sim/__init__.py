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

from streamid.sim._common import Trace
from streamid.sim.boucwen import (
    BENCHMARK_PERIOD_NS,
    BoucWenParams,
    bouc_wen_operator,
    integrate_bouc_wen,
    simulate_bouc_wen,
    simulate_bouc_wen_multisine,
    simulate_bouc_wen_periodic,
)
from streamid.sim.registry import ALIASES, DEVICES, Device, device_names, get_device
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
