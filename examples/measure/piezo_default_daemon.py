"""The bundled 20 kHz piezo log through a daemon with its default configuration (issue 38, item 5's first target).

Usage: ``python examples/measure/piezo_default_daemon.py [LOOPS]`` (default 4: 80 s of stream)

Starts ``streamid daemon --listen tcp/127.0.0.1:PORT`` (a free loopback port; every other setting the embedded
default: 10 s windows, an update every second, the ``.rrd`` sink in a temporary directory), subscribes to the
stream's model, rejected-challenger and status keys, runs ``streamid replay piezo_sim_20khz --connect ... --loop
LOOPS`` in real time, and prints one JSON line: seconds from the replay's start to the first model, the decisions
(published or rejected) and the gaps between them, the updates' ``identification_s``, the windows' counters, the
daemon's resident memory (``VmRSS``, sampled every 0.25 s; its evaluation helper processes apart), the published
models' held-out free-run R^2 and ``metrics.search_rows``. Run it alone on the machine (``flock``): it is a timing.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import numpy as np

from streamid.transport import Bus, ZenohSettings

PY = [sys.executable, "-m", "streamid"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def main(loops: int) -> dict[str, Any]:
    ep = f"tcp/127.0.0.1:{_free_port()}"
    daemon = subprocess.Popen([*PY, "daemon", "--listen", ep], cwd=tempfile.mkdtemp(prefix="piezo-default-"),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(ln.rstrip() for ln in daemon.stdout or ()), daemon=True).start()
    events: list[tuple[float, str, dict[str, Any]]] = []
    rss: list[tuple[float, float]] = []
    stop = threading.Event()

    def on(key: str, payload: bytes) -> None:
        try:
            events.append((time.monotonic(), key.rsplit("/", 1)[-1], json.loads(payload)))
        except ValueError:
            pass

    def sample_rss() -> None:
        while not stop.wait(0.25):
            rss.append((_rss_mb(daemon.pid), sum(_rss_mb(c) for c in _children(daemon.pid))))

    try:
        deadline = time.monotonic() + 60
        while not any("serving on" in ln for ln in lines) and time.monotonic() < deadline and daemon.poll() is None:
            time.sleep(0.05)
        threading.Thread(target=sample_rss, daemon=True).start()
        with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as bus:
            for kind in ("model", "rejected", "status"):
                bus.subscribe(f"streamid/piezo/{kind}", on)
            time.sleep(0.5)
            t0 = time.monotonic()
            subprocess.run([*PY, "replay", "piezo_sim_20khz", "--connect", ep, "--loop", str(loops)],
                           capture_output=True, text=True, timeout=60 + 30 * loops, check=True)
            replay_s = time.monotonic() - t0
            time.sleep(4.0)  # the last window's decision
    finally:
        stop.set()
        daemon.terminate()
        daemon.wait(30)
    decisions = [(t, k, doc) for t, k, doc in events if k in ("model", "rejected")]
    status = [doc for _, k, doc in events if k == "status"]
    first = next((t - t0 for t, k, _ in decisions if k == "model"), None)
    gaps = np.diff([t for t, _, _ in decisions]) if len(decisions) > 1 else np.array([np.nan])
    secs = [float(doc["identification_s"]) for _, _, doc in decisions if "identification_s" in doc]
    published = [doc for _, k, doc in decisions if k == "model"]
    return {
        "replay_s": round(replay_s, 2),
        "first_model_s": None if first is None else round(first, 2),
        "decisions": len(decisions), "published": len(published),
        "gap_median_s": round(float(np.median(gaps)), 3), "gap_max_s": round(float(np.max(gaps)), 3),
        "identification_s_median": round(float(np.median(secs)), 3) if secs else None,
        "identification_s_max": round(float(np.max(secs)), 3) if secs else None,
        "windows": status[-1].get("windows") if status else None,
        "rss_daemon_max_mb": round(max((a for a, _ in rss), default=0.0), 1),
        "rss_daemon_median_mb": round(float(np.median([a for a, _ in rss])), 1) if rss else None,
        "rss_helpers_max_mb": round(max((b for _, b in rss), default=0.0), 1),
        "r2_fr_val": [round(float(doc["metrics"]["r2_fr_val"]), 4) for doc in published],
        "search_rows": published[0]["model"]["metrics"].get("search_rows") if published else None,
    }


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]) if len(sys.argv) > 1 else 4)))
