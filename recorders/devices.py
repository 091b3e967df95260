"""Simulated device recorders: seeded simulations written as streamid MCAP logs.

The devices are those of :mod:`streamid.sim`'s registry that have a
``stream`` (piezo 20 kHz, mr_damper 200 Hz, reactor 5 Hz): the registry gives
the simulator, period, channel names, stream and batch size; this module only
writes the record as sample batches, as the device's acquisition board would
publish them.

Every log records the device, simulator, seed and sample count in its
``streamid`` metadata record. A log of a drifting device
(``drift_at_s=...``, :func:`streamid.sim.simulate_drift`) also records the
true change: ``drift_at_s`` (as asked), ``drift_at_ns`` (time of the first
sample of the changed device), ``drift_change``, ``drift_parameters`` and
``drift_lag_samples`` (samples from there to the first output that can differ),
so that a benchmark reads the true change time back from the log.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from streamid.errors import ConfigError
from streamid.logs import write_arrays_log
from streamid.sim import DEVICES, DRIFTS, Device, drift_start_ns, simulate_drift
from streamid.wire.keys import check_stream_name

__all__ = ["recorded_devices", "simulate_device_log"]


def recorded_devices() -> Mapping[str, Device]:
    """The devices of :data:`streamid.sim.DEVICES` that have a recorder (a ``stream``), by name."""
    return {name: d for name, d in DEVICES.items() if d.stream is not None}


def simulate_device_log(
    device: str,
    path: str | os.PathLike[str],
    *,
    seed: int = 0,
    duration_s: float | None = None,
    batch_size: int | None = None,
    stream: str | None = None,
    split: bool = False,
    drift_at_s: float | None = None,
    drift_change: float = 0.2,
) -> dict[str, Any]:
    """Simulate ``device`` for ``duration_s`` and write the record to ``path``.

    Parameters
    ----------
    device : str
        One of :func:`recorded_devices` ("piezo", "mr_damper", "reactor").
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
    drift_at_s : float, optional
        Simulate a drifting device (:data:`streamid.sim.DRIFTS`: mr_damper, piezo) whose
        output-level parameters change by ``drift_change`` at this time from the record's start.
    drift_change : float
        Relative change of those parameters (0.2 = +20 %); used with ``drift_at_s``.

    Returns
    -------
    dict
        What was written: device, path, samples, messages, period_ns, seed, stream
        (and drift_at_ns, drift_change for a drifting device).
    """
    devices = recorded_devices()
    spec = devices.get(device)
    if spec is None or spec.stream is None:
        raise ConfigError(f"device must be one of {', '.join(devices)}; got {device!r}")
    duration = spec.default_seconds if duration_s is None else float(duration_s)
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
    if drift_at_s is None:
        trace = spec.simulate(n, np.random.default_rng(seed))
        simulator = spec.simulate.__module__ + "." + spec.simulate.__name__
    else:
        drift = DRIFTS.get(device)
        if drift is None:
            raise ConfigError(f"a drifting device (drift_at_s) must be one of {', '.join(DRIFTS)}; got {device!r}")
        trace = simulate_drift(device, duration, drift_at_s, drift_change, np.random.default_rng(seed))
        simulator = simulate_drift.__module__ + "." + simulate_drift.__name__
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
        "simulator": simulator,
        "seed": str(seed),
        "n_samples": str(n),
        "period_ns": str(spec.period_ns),
        "input": spec.input_name,
        "output": spec.output_name,
    }
    result: dict[str, Any] = {}
    if drift_at_s is not None:
        drift = DRIFTS[device]
        result = {"drift_at_ns": drift_start_ns(device, drift_at_s), "drift_change": float(drift_change)}
        meta.update({
            "model": spec.description + f"; drifting: {', '.join(drift.parameters)} x (1 + drift_change) "
                                        "from drift_at_ns on",
            "drift_at_s": repr(float(drift_at_s)),
            "drift_at_ns": str(result["drift_at_ns"]),
            "drift_change": repr(float(drift_change)),
            "drift_parameters": " ".join(drift.parameters),
            "drift_lag_samples": str(drift.lag_samples),
        })
    messages = write_arrays_log(
        path, name, {spec.input_name: np.asarray(u, np.float64)},
        {spec.output_name: np.asarray(y, np.float64)}, period_ns=spec.period_ns,
        t0_ns=int(t_ns[0]), batch_size=batch, split=split, metadata=meta,
    )
    return {"device": device, "path": str(Path(path)), "samples": n, "messages": messages,
            "period_ns": spec.period_ns, "seed": seed, "stream": name, **result}
