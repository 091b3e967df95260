"""Simulated device recorders: seeded simulations written as streamid MCAP logs.

Each device runs one of streamid's simulators (``streamid.sim``; the physics
is documented in the simulator's module) and writes its record as sample
batches, as the device's acquisition board would publish them:

- ``piezo``: 20 kHz, ``streamid.sim.piezo.simulate_piezo``, ``voltage_V`` ->
  ``deflection_um``, 200 samples (10 ms) per batch, stream ``piezo``;
- ``mr_damper``: 200 Hz, ``streamid.sim.mrdamper.simulate_mr_damper``,
  ``velocity_cm_s`` -> ``force_N``, 20 samples (100 ms) per batch, stream
  ``mr_damper_sim``;
- ``reactor``: 5 Hz, ``streamid.sim.reactor.simulate_reactor``,
  ``initiator_flow`` -> ``molecular_weight`` (dimensionless flow, g/mol), 5
  samples (1 s) per batch, stream ``reactor`` (default 192 s = the paper's 960 samples).

Every log records the device, simulator, seed and sample count in its
``streamid`` metadata record.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from streamid.errors import ConfigError
from streamid.wire.keys import check_stream_name
from streamid.logs import write_arrays_log

__all__ = ["DeviceSpec", "DEVICES", "simulate_device_log"]


@dataclass(frozen=True)
class DeviceSpec:
    """How one simulated device is recorded."""

    name: str
    simulator: tuple[str, ...]  # candidate "module:function" specs, first found is used
    period_ns: int
    stream: str
    input_name: str
    output_name: str
    batch_size: int
    default_duration_s: float
    description: str

    @property
    def rate_hz(self) -> float:
        return 1e9 / self.period_ns

    def load(self) -> Any:
        """The simulator function ``f(n_samples, rng) -> Trace``."""
        errors = []
        for spec in self.simulator:
            module, _, attr = spec.partition(":")
            try:
                return getattr(importlib.import_module(module), attr)
            except (ModuleNotFoundError, AttributeError) as exc:
                errors.append(f"{spec}: {exc}")
        raise ConfigError(
            f"the simulator of device {self.name!r} is not available in this streamid "
            f"(tried {'; '.join(errors)})"
        )


DEVICES: dict[str, DeviceSpec] = {
    d.name: d
    for d in (
        DeviceSpec(
            "piezo", ("streamid.sim.piezo:simulate_piezo",), 50_000, "piezo",
            "voltage_V", "deflection_um", 200, 10.0,
            "piezoelectric unimorph micromanipulator: Bouc-Wen hysteresis driving the first "
            "bending mode, optical sensor noise (streamid.sim.piezo)",
        ),
        DeviceSpec(
            "mr_damper",
            ("streamid.sim.mrdamper:simulate_mr_damper", "streamid.sim.mr_damper:simulate_mr_damper",
             "streamid.sim:simulate_mr_damper"),
            5_000_000, "mr_damper_sim", "velocity_cm_s", "force_N", 20, 60.0,
            "magneto-rheological damper, Spencer phenomenological Bouc-Wen model driven by "
            "band-limited velocity (streamid.sim)",
        ),
        DeviceSpec(
            "reactor", ("streamid.sim.reactor:simulate_reactor",), 200_000_000, "reactor",
            "initiator_flow", "molecular_weight", 5, 192.0,
            "continuous MMA polymerization reactor of the paper, eq. 17 (streamid.sim.reactor)",
        ),
    )
}


def simulate_device_log(
    device: str,
    path: str | os.PathLike[str],
    *,
    seed: int = 0,
    duration_s: float | None = None,
    batch_size: int | None = None,
    stream: str | None = None,
    split: bool = False,
) -> dict[str, Any]:
    """Simulate ``device`` for ``duration_s`` and write the record to ``path``.

    Parameters
    ----------
    device : {"piezo", "mr_damper", "reactor"}
    path : str or Path
        MCAP file to write.
    seed : int
        Seed of the simulator's random generator (same seed, same log).
    duration_s : float, optional
        Length of the record (default: the device's default).
    batch_size : int, optional
        Samples per batch (default: the device's).
    stream : str, optional
        Stream name (default: the device's).
    split : bool
        Publish inputs on ``.../u`` and outputs on ``.../y`` instead of ``.../samples``.

    Returns
    -------
    dict
        What was written: device, path, samples, messages, period_ns, seed, stream.
    """
    spec = DEVICES.get(device)
    if spec is None:
        raise ConfigError(f"device must be one of {', '.join(DEVICES)}; got {device!r}")
    duration = spec.default_duration_s if duration_s is None else float(duration_s)
    if not duration > 0:
        raise ConfigError(f"duration_s must be > 0 seconds; got {duration_s!r}")
    n = int(round(duration * 1e9 / spec.period_ns))
    if n < 1:
        raise ConfigError(
            f"duration_s must cover at least one sample period ({spec.period_ns / 1e9} s); got {duration}"
        )
    if not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer; got {seed!r}")
    name = check_stream_name(stream if stream is not None else spec.stream)
    batch = spec.batch_size if batch_size is None else int(batch_size)
    trace = spec.load()(n, np.random.default_rng(seed))
    t_ns, u, y = trace
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if t_ns.size > 1 and int(t_ns[1] - t_ns[0]) != spec.period_ns:
        raise ConfigError(  # pragma: no cover - guards against a simulator change
            f"simulator of {device!r} returned period {int(t_ns[1] - t_ns[0])} ns, "
            f"expected {spec.period_ns} ns"
        )
    meta = {
        "source": f"simulated device '{device}'",
        "device": device,
        "model": spec.description,
        "simulator": spec.load().__module__ + "." + spec.load().__name__,
        "seed": str(seed),
        "n_samples": str(n),
        "period_ns": str(spec.period_ns),
        "input": spec.input_name,
        "output": spec.output_name,
    }
    messages = write_arrays_log(
        path, name, {spec.input_name: np.asarray(u, np.float64)},
        {spec.output_name: np.asarray(y, np.float64)}, period_ns=spec.period_ns,
        t0_ns=int(t_ns[0]), batch_size=batch, split=split, metadata=meta,
    )
    return {"device": device, "path": str(Path(path)), "samples": n, "messages": messages,
            "period_ns": spec.period_ns, "seed": seed, "stream": name}
