"""examples/controller.py end to end: a real daemon, the bundled MR damper log replayed, the example as users run it.

The daemon (``streamid daemon``, embedded defaults) and the example are real processes on a fresh
``tcp/127.0.0.1`` port; the log is replayed at 5 times real time, twice.  The example follows the
served model sample by sample (``streamid.Predictor``) and judges its 0.2 s forecasts as the outputs arrive.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

from conftest import STREAMID, endpoint

from replay.player import ReplayConfig, replay_log
from streamid.logs.bundled import bundled_log
from streamid.transport import ZenohSettings

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "controller.py"


def test_the_controller_example_follows_the_served_model_and_its_forecasts_hold(tmp_path: Path) -> None:
    ep = endpoint()
    daemon = subprocess.Popen([*STREAMID, "daemon", "--listen", ep, "--no-rerun", "--state-dir", str(tmp_path)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    example = None
    try:
        time.sleep(1.0)
        example = subprocess.Popen([sys.executable, str(EXAMPLE), "--connect", ep, "--stream", "mr_damper",
                                    "--seconds", "12", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True)
        time.sleep(1.5)  # its subscriptions are declared
        replay_log(bundled_log("mr_damper.mcap"), ZenohSettings(connect=(ep,)),
                   ReplayConfig(rate=5.0, loops=2, wait_subscribers_s=15.0))
        out, err = example.communicate(timeout=60)
    finally:
        for p in (example, daemon):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(10)
    assert example.returncode == 0, err[-2000:]
    docs = [json.loads(line) for line in out.splitlines()]
    reports = [d for d in docs if "format" not in d]
    events = [d for d in docs if "format" in d]  # what the status said (on_event), as documents
    assert all(d["format"] == "streamid.status-event/1" and d["stream"] == "mr_damper" for d in events), events
    judged = [r for r in reports if r["forecasts"]]
    assert len(judged) >= 10, reports  # a report per second of stream time once a model was served
    versions = [r["version"] for r in judged]
    assert versions == sorted(versions) and versions[0] >= 1  # models swapped in as published, never back
    r2 = sorted(r["forecast_r2"] for r in judged)
    # published models free-run at R2 >= 0.9 over their 3 s held-out parts (issue 12's floor); a forecast
    # 0.2 s from measured samples is held to the same floor, in every second but the loop point's
    assert r2[1] >= 0.9, r2
    print("events:", events)
    print("forecast R2 per second:", [round(v, 4) for v in r2], "versions", sorted(set(versions)))


def test_a_report_line_reads_as_the_docstring_shows() -> None:
    spec = importlib.util.spec_from_file_location("controller_example", EXAMPLE)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    r = {"t_s": 14.6, "version": 1, "output": "force_N", "osa_rms": 3.0382, "forecasts": 4, "forecast_r2": 0.98114,
         "beyond_range": []}
    shown = [ln.strip() for ln in mod.__doc__.splitlines() if ln.strip().startswith("t ")]
    assert mod.report_line(r, 0.2) == shown[0] == ("t     14.60 s  v1    force_N: one-step rms 3.038, 0.2 s forecasts 4, "
                                                   "R2 0.9811, beyond range: -")
    r.update(osa_rms=None, forecast_r2=None, beyond_range=["velocity_cm_s"])
    assert mod.report_line(r, 0.2).endswith("one-step rms -, 0.2 s forecasts 4, R2 -, beyond range: velocity_cm_s")
