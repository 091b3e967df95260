"""benchmarks.ablation: issue 37's targets judged per row, and a run of the defaults with a field changed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.ablation import main, verdict


def test_the_verdict_names_the_first_target_missed() -> None:
    row = "rlc [id->test]"  # --paper worst 0.9214, FROLS best 0.9412
    assert verdict(row, 0.9662, 0.9536) == "met"
    assert verdict(row, 0.9662, 0.9200) == "worst < paper's 0.9214"
    assert verdict(row, 0.9662, 0.9400) == "worst 0.0262 under median"
    assert verdict(row, 0.9410, 0.9400) == "median < FROLS 0.9412"
    assert verdict("reactor_sim [steps->sines]", 0.99999996, 0.99999960) == "met"  # at the table's 4 decimals
    assert verdict("mr_damper", 0.9861, 0.9821) == "met" and verdict("mr_damper", 0.979, 0.975).startswith("mark")


def test_a_run_reports_every_row_and_writes_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rows.json"
    changes = {"generations": 4, "restarts": 2, "more_restarts": 0, "refine_iterations": 0}
    assert main(["--systems", "reactor_sim", "--seeds", "0,1", "--jobs", "1", "--changes", json.dumps(changes),
                 "--json", str(out)]) == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["changes"] == changes and len(doc["rows"]) == 3  # the reactor's three pairs
    for r in doc["rows"]:
        assert len(r["fr_val"]) == 2 and r["worst"] == min(r["fr_val"]) and r["verdict"] == verdict(
            r["target"], r["median"], r["worst"])
    assert "rows meet issue 37's targets" in capsys.readouterr().out
