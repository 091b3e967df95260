"""A stream that cannot be identified as it is sent is never ``ok`` (issue 38 item 3).

A real daemon whose bound on one identification's memory is 64 MiB, fed a 20 kHz stream whose 10 s window would need
far more: every batch is refused and counted as before, and now the stream's status is degraded with the reason
(``degraded_reason``), which ``streamid status`` prints; the same daemon serves a stream that fits as ``ok``.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
from conftest import STREAMID, endpoint, stop_process, wait_until, start_daemon

from streamid.transport import Bus, ZenohSettings
from streamid.wire.codec import SampleBatch, encode

CONFIG = """
[daemon]
max_identification_bytes = 67108864
status_every_s = 0.5
helper = false

[defaults]
window_s = 10.0
cold_generations = 3
warm_generations = 2
neurons = 3
max_lag_y = 2
max_lag_u = 2
population = 8
min_r2_osa = -1e9
min_r2_fr = -1e9
"""


def _status(ep: str, stream: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, "status", "--connect", ep, "--stream", stream, "--timeout", "1.5"],
                          capture_output=True, text=True, timeout=60)


def test_a_window_too_large_for_the_bound_makes_the_stream_degraded_not_ok(tmp_path: Path) -> None:
    ep = endpoint()
    proc = start_daemon(tmp_path, ep, CONFIG)
    try:
        with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as bus:
            fast = bus.publisher("streamid/fast/samples", block=True)
            slow = bus.publisher("streamid/slow/samples", block=True)
            rng = np.random.default_rng(0)
            for k in range(20):  # 20 kHz: a 10 s window is 200,000 samples; 200 Hz: 2,000
                u = rng.standard_normal(1000)
                fast.put(encode(SampleBatch("fast", k, k * 1000 * 50_000, 50_000, None, {"v": u}, {"x": u})))
                slow.put(encode(SampleBatch("slow", k, k * 1000 * 5_000_000, 5_000_000, None, {"v": u}, {"x": u})))
            out: list[subprocess.CompletedProcess[str]] = []
            assert wait_until(lambda: bool(out.append(_status(ep, "fast")) or "DEGRADED" in out[-1].stdout), 30), \
                out[-1].stdout + out[-1].stderr
            line = next(ln for ln in out[-1].stdout.splitlines() if ln.startswith("fast"))
            assert "cannot be identified as sent: a window of 200000 samples" in line, line
            assert "daemon.max_identification_bytes is 64 MiB" in line, line
            docs = [json.loads(p) for _, p in bus.get("streamid/fast/status", 2.0)]
            assert docs and docs[0]["degraded"] is True and "200000 samples" in docs[0]["degraded_reason"], docs
            rows: list[str] = []
            assert wait_until(lambda: bool(rows.append(next((ln for ln in _status(ep, "slow").stdout.splitlines()
                                                         if ln.startswith("slow")), "")) or re.search(r" v[1-9]\d* ", rows[-1]) is not None), 30), rows
            assert "DEGRADED" not in rows[-1], rows[-1]  # a stream that fits the bound: identified, and ok
    finally:
        stop_process(proc)
