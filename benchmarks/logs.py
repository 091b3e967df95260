"""Benchmarks of the log path, for ``streamid bench`` (entry point ``streamid.benchmarks: logs``).

- :func:`bench_max_speed`: replay -> Zenoh -> recorder at full speed, end to end
  (the recorder is a separate ``streamid record`` process, as in use).
- :func:`bench_realtime`: replay of the simulated 20 kHz piezo log at real time
  into a recorder process: distribution of |put time - scheduled time|.

Both check that the recorder received every sample.
"""

from __future__ import annotations

import dataclasses
import json
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from replay.player import ReplayConfig, replay_log
from streamid.errors import StreamidError
from streamid.logs import write_arrays_log
from streamid.transport import ZenohSettings

__all__ = ["bench_max_speed", "bench_realtime", "bench"]


def _free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _run_against_recorder(log: Path, n_messages: int, config: ReplayConfig,
                          workdir: Path) -> tuple[Any, dict[str, Any]]:
    ep = _free_endpoint()
    out = workdir / "recorded.mcap"
    rec = subprocess.Popen(
        [sys.executable, "-m", "streamid", "record", str(out), "--listen", ep,
         "--max-messages", str(n_messages), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        report = replay_log(log, ZenohSettings(connect=(ep,)),
                            dataclasses.replace(config, wait_subscribers_s=30.0))
        stdout, stderr = rec.communicate(timeout=120)
    finally:
        if rec.poll() is None:
            rec.kill()
            rec.communicate(timeout=10)
    if rec.returncode != 0:
        raise StreamidError(f"recorder failed ({rec.returncode}): {stderr.strip()[-500:]}")
    stats = json.loads(stdout.strip().splitlines()[-1])
    return report, stats


def bench_max_speed(samples: int = 2_000_000, batch_size: int = 1000, seed: int = 0) -> dict[str, Any]:
    """Replay a synthetic log (1 input + 1 output, float64) at max speed into a recorder process.

    Returns ``samples_per_s`` end to end (first put to the recorder's receipt
    of the last message), the sender's rate, and ``lost`` samples.
    """
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(prefix="streamid-bench-") as tmp:
        work = Path(tmp)
        log = work / "source.mcap"
        n_msgs = write_arrays_log(log, "bench", {"u": rng.standard_normal(samples)},
                                  {"y": rng.standard_normal(samples)}, period_ns=50_000,
                                  batch_size=batch_size)
        report, stats = _run_against_recorder(log, n_msgs, ReplayConfig(max_speed=True), work)
    e2e_s = (stats["last_ns"] - report.started_ns) / 1e9
    return {
        "samples": report.samples, "batch_size": batch_size, "messages": report.messages,
        "samples_per_s": report.samples / e2e_s, "sender_samples_per_s": report.samples_per_s,
        "lost": report.samples - stats["samples"], "seq_gaps": stats["seq_gaps"],
    }


def bench_realtime(duration_s: float = 10.0, seed: int = 0) -> dict[str, Any]:
    """Replay the simulated 20 kHz piezo log (200 samples/batch) at rate 1.0 into a recorder process.

    Returns the timing error distribution in µs (``p50``, ``p90``, ``p99``,
    ``max``, ``mean``) and ``lost`` samples.
    """
    from recorders.devices import simulate_device_log

    with tempfile.TemporaryDirectory(prefix="streamid-bench-") as tmp:
        work = Path(tmp)
        log = work / "piezo.mcap"
        info = simulate_device_log("piezo", log, seed=seed, duration_s=duration_s)
        report, stats = _run_against_recorder(log, info["messages"], ReplayConfig(rate=1.0), work)
    out = dict(report.timing_error_us())
    out.update({"samples": report.samples, "lost": report.samples - stats["samples"],
                "wall_s": report.wall_s, "log_span_s": report.log_span_s})
    return out


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench`` provider: yields ``benchmarks.kit.Measurement`` rows."""
    from benchmarks.kit import Measurement

    quick = bool(getattr(options, "quick", False))
    repeat = max(1, int(getattr(options, "repeat", 1)))
    seed = int(getattr(options, "seed", 0))
    runs = [bench_max_speed(samples=400_000 if quick else 2_000_000, batch_size=1000, seed=seed + i)
            for i in range(repeat)]
    yield Measurement("logs", "replay -> zenoh -> record, max speed, 1000 samples/batch",
                      "end-to-end throughput", "samples/s", tuple(r["samples_per_s"] for r in runs),
                      note=f"{runs[0]['samples']} samples, lost {sum(r['lost'] for r in runs)}")
    runs200 = [bench_max_speed(samples=200_000 if quick else 1_000_000, batch_size=200, seed=seed + i)
               for i in range(repeat)]
    yield Measurement("logs", "replay -> zenoh -> record, max speed, 200 samples/batch",
                      "end-to-end throughput", "samples/s", tuple(r["samples_per_s"] for r in runs200),
                      note=f"{runs200[0]['samples']} samples, lost {sum(r['lost'] for r in runs200)}")
    rt = [bench_realtime(duration_s=2.0 if quick else 10.0, seed=seed + i)
          for i in range(1 if quick else min(repeat, 3))]
    for q in ("p50", "p99", "max"):
        yield Measurement("logs", "replay 20 kHz piezo log at real time (200 samples/batch)",
                          f"timing error {q}", "µs", tuple(r[q] for r in rt),
                          note=f"put start - schedule, over {int(rt[0]['n'])} batches, lost "
                               f"{sum(r['lost'] for r in rt)} samples")
