"""``streamid bench --only engine --quick`` runs from the command line and gives every row (a smoke test).

The benchmark figures themselves are measured by ``streamid bench``, never asserted here; this keeps the
engine section's code from rotting unnoticed (no other test runs it).
"""

from __future__ import annotations

import argparse
import json
import math

import pytest

from benchmarks import command


def test_bench_engine_quick_gives_every_row(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    command.register(parser.add_subparsers())
    assert command.run(parser.parse_args(["bench", "--only", "engine", "--quick", "--json"])) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["failures"] == []
    rows = doc["measurements"]
    assert {r["section"] for r in rows} == {"engine"}
    cases = {r["case"] for r in rows}
    for case in ("reactor G=400 M=10 (paper), one core", "MR damper, paper G=200 M=10", "MR damper, streamid defaults",
                 "piezo G=100 M=13 (paper)", "controller loop: Predictor on the MR damper (M=10)",
                 "scaling N=480 M=10", "scaling N=2000 M=40"):
        assert case in cases, (case, sorted(cases))
    loop = {r["metric"]: r for r in rows if r["case"].startswith("controller loop")}
    assert set(loop) == {"us_per_sample", "us_per_forecast_1s", "ms_per_50_forecasts_1s", "us_per_step"}
    assert all(r["median"] > 0 for r in loop.values())
    assert all(math.isfinite(r["median"]) for r in rows if r["metric"] != "lags y1,u1,u2(,y2)"), rows
