"""Reliability, bad input: a bad daemon configuration is refused at start, in one line naming the key.

The real ``streamid daemon`` CLI in a subprocess.  Moved out of tests/test_reliability_bad_input.py (the same
test): that module runs alone (its timed plan of every bad input at once, tests/alone.py), and a refused start
measures no time, so it need not keep the other test process waiting.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from conftest import STREAMID, endpoint


@pytest.mark.parametrize(
    ("toml", "named"),
    [
        ("[defaults]\nwindow_s = 'ten'\n", "defaults.window_s must be a number of seconds > 0; got 'ten' (str)"),
        ("[defaults]\nneurons = 4.5\n", "defaults.neurons must be an integer >= 1; got 4.5 (float)"),
        ("[daemon]\nworkers = true\n", "daemon.workers must be an integer in [1, 64]; got True (bool)"),
        ("[streams.a]\nwindw_s = 1.0\n", "unknown key 'streams.a.windw_s'"),
        ("[streams.a.engine]\nde_f = 'x'\n", "CoEAConfig.de_f must be a number"),
        ("[defaults]\nseed = -1\n", "seed must be an integer >= 0; got -1"),
        ("[defaults]\nmin_r2_osa = 2.0\n", "min_r2_osa must be a number <= 1"),
    ],
)
def test_bad_config_is_refused_at_start_naming_the_key(tmp_path: Path, toml: str, named: str) -> None:
    cfg = tmp_path / "d.toml"
    cfg.write_text(toml)
    ep = endpoint()
    out = subprocess.run([*STREAMID, "daemon", "--config", str(cfg), "--listen", ep, "--no-rerun"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    assert named in out.stderr and str(cfg) in out.stderr
    assert "serving on" not in out.stderr  # refused before opening anything
