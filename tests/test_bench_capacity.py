"""``streamid bench --only capacity`` (issue 38 item 4) in a tiny configuration: its rows and their structure.

A real daemon, a real publisher and a real subscriber on loopback, one 200 Hz stream for 12 s with 2 s windows; the
engine on a 2,000-sample record. The figures themselves are the bench's (docs/benchmarks.md), not asserted here.
"""

from __future__ import annotations

import json
import math

import pytest

from benchmarks.capacity import CapacityPlan, capacity_measurements
from benchmarks.command import BUILTIN_PROVIDERS, ON_REQUEST, section_names

TINY = CapacityPlan(ladders=((200.0, (1,)),), seconds=12.0, engine_lengths=(2_000,), offline_lengths=(2_000,),
                    engine_timeout_s=240.0,
                    daemon_toml="[defaults]\nwindow_s = 2.0\nupdate_every_s = 1.0\ncold_generations = 30\n")


def test_the_section_is_registered_and_runs_only_when_named() -> None:
    assert BUILTIN_PROVIDERS["capacity"] == "benchmarks.capacity:bench"
    assert "capacity" in section_names() and "capacity" in ON_REQUEST


def test_a_tiny_capacity_run_gives_every_row() -> None:
    rows = list(capacity_measurements(TINY))
    by = {(m.case, m.metric): m for m in rows}
    trial = "1 x 200 Hz, 12 s"
    for metric in ("decision latency p50", "decision latency p99", "streams served", "coalesced windows",
                   "decisions per stream", "median served FR R2", "RSS per stream", "daemon peak RSS",
                   "last stream's first decision"):
        assert (trial, metric) in by, (metric, sorted(by))
    assert all(m.section == "capacity" for m in rows)
    served = by[(trial, "streams served")]
    assert served.values == (1.0,) and served.note == "of 1"  # one stream, served: 2 s windows over 12 s
    decisions = by[(trial, "decisions per stream")]
    assert len(decisions.values) == 1 and decisions.values[0] >= 3
    assert 0 < by[(trial, "decision latency p50")].median <= by[(trial, "decision latency p99")].median
    assert "refreshes" in by[(trial, "decision latency p50")].note
    assert 2.0 <= by[(trial, "last stream's first decision")].median < 12.0  # a 2 s window first, within the run
    assert "after a stream's first decision" in by[(trial, "coalesced windows")].note
    assert by[(trial, "daemon peak RSS")].median > 50  # MB: a Python process with numpy and zenoh
    ladder = by[("200 Hz, one daemon", "streams kept up")]
    assert ladder.values[0] == (1.0 if decisions.values[0] >= 1 else 0.0) and "tried 1: " in ladder.note
    for engine in ("online cold update, 2000-sample window (2 kHz MR damper)",
                   "offline identify, 2000 samples (2 kHz MR damper, online settings)"):
        assert by[(engine, "identification time")].median > 0 and by[(engine, "peak memory")].median > 50
        fr = by[(engine, "R2 FR held out")].median
        assert math.isnan(fr) or fr <= 1.0  # NaN: the free run diverged on the held-out samples (a figure too)
    common = by[("online cold update, 2000-sample window (2 kHz MR damper)", "R2 FR common record")]
    assert "another excitation" in common.note and (math.isnan(common.median) or common.median <= 1.0)
    assert ("offline identify, 2000 samples (2 kHz MR damper, online settings)", "R2 FR common record") not in by
    refresh = [m for m in rows if m.metric == "time per new sample"]
    assert len(refresh) == 1 and 0 < refresh[0].median < 1000  # microseconds (a sanity bound, not a timing claim)


def test_engine_lengths_take_stream_changes_an_offset_and_the_common_records_length(
        capsys: pytest.CaptureFixture[str]) -> None:
    from benchmarks.capacity import _main

    args = ["engine", "2000", "--seeds", "1", "--record", "6000", "--common-samples", "4000"]
    assert _main(args) == 0
    base = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert _main([*args, "--stream", '{"neurons": 3, "cold_generations": 5}', "--offset", "3000"]) == 0
    small = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert base["kind"] and small["kind"] and base["seed"] == small["seed"] == 1
    assert small["r2_fr_common"] != base["r2_fr_common"]  # another window, another network: another model
    assert _main([*args, "--stream", '{"neurons": 0}']) == 0  # a bad change: the child's error, reported
    assert "skipped" in json.loads(capsys.readouterr().out.strip().splitlines()[-1])
