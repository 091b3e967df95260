"""``streamid view`` as a process: every segment of a recording, the real viewer headless, repair, errors."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import STREAMID

from streamid.commands.main import main
from streamid.viz import rrd_files
from streamid.viz.rerun_view import Viz, VizSettings
from streamid.viz.screenshot import rerun_cli

sys.path.insert(0, str(Path(__file__).parent))
from rrd_writer import report  # noqa: E402


def view(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, "view", *args], capture_output=True, text=True, timeout=120)


def segments(base: Path, n: int = 6, **settings: object) -> list[str]:
    """``n`` updates of stream ``s`` into ``base``, one segment each; R² free run rises from 0.38 to 0.3 + 0.08 n."""
    viz = Viz(VizSettings(rrd=str(base), rrd_rotate_mb=0.05, recording_id="view-test", **settings))  # type: ignore[arg-type]
    viz.add_stream("s")
    for v in range(1, n + 1):
        r = report(v, n_val=400)
        viz.log_update(dataclasses.replace(r, metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.3 + 0.08 * v}))
        viz.flush()
    viz.close()
    return viz.files


def test_errors_name_the_file_and_the_accepted_form(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)

    def run(*argv: str) -> subprocess.CompletedProcess[str]:  # in-process: the same main() as the command
        rc = main(["view", *argv])
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(argv, rc, out, err)

    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "fake.rrd").write_text("hello")
    form = "give a Rerun recording FILE.rrd"
    cases = {
        ("missing.rrd",): "no file 'missing.rrd'",
        ("notes.txt",): "'notes.txt' is not an .rrd file (its name must end in .rrd)",
        ("fake.rrd",): "'fake.rrd' is not a Rerun recording: it does not start with RRF",
        ("--repair", "missing.rrd"): "no file 'missing.rrd'",
    }
    for argv, message in cases.items():
        res = run(*argv)
        assert res.returncode == 2, (argv, res.stderr)
        assert f"streamid view: error: {message}" in res.stderr and form in res.stderr, (argv, res.stderr)
    res = run("fake.rrd", "-o", "x.rrd")
    assert res.returncode == 2 and "-o 'x.rrd' goes with --repair" in res.stderr
    res = run("--repair", "a.rrd", "b.rrd", "-o", "x.rrd")
    assert res.returncode == 2 and "-o names the copy of one file; got 2 files (a.rrd, b.rrd)" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fake.rrd", "notes.txt"]  # nothing written


def test_print_command_opens_every_segment_newest_first_on_loopback(tmp_path: Path) -> None:
    base = tmp_path / "d.rrd"
    files = segments(base, n=5, rrd_keep=4)
    assert not base.exists() and len(files) == 4  # the first segments were removed by the bound
    last = Path(files[-2])  # a segment with data, cut as a SIGKILL leaves it: no footer
    last.write_bytes(last.read_bytes()[: last.stat().st_size * 2 // 3])
    res = view(str(base), "--print-command", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["files"] == files and doc["no_footer"] == [str(last)] and doc["empty"] == []
    assert doc["command"] == [rerun_cli(), "--bind", "127.0.0.1", *reversed(files)]  # the fullest layout first
    res = view(str(base), "--print-command")
    assert res.returncode == 0 and res.stdout.split() == doc["command"]
    assert "streamid view: 4 files" in res.stderr
    assert f"{last} has no footer" in res.stderr and f"streamid view --repair {last}" in res.stderr


def test_repair_writes_a_verified_copy_and_says_what_it_recovered(tmp_path: Path) -> None:
    files = segments(tmp_path / "r.rrd", n=3)
    cut = tmp_path / "cut.rrd"
    whole = Path(files[1]).read_bytes()
    cut.write_bytes(whole[: len(whole) - 5000])  # the footer and the last chunks gone
    assert not rrd_files.verify(cut, rerun=rerun_cli())[0]
    res = view("--repair", str(cut), "-o", str(tmp_path / "fixed.rrd"), "--json")
    assert res.returncode == 0, res.stderr
    rep = json.loads(res.stdout)["repaired"]
    assert len(rep) == 1 and rep[0]["output"] == str(tmp_path / "fixed.rrd") and rep[0]["chunks"] > 10
    assert rep[0]["source_had_footer"] is False and rep[0]["source_bytes"] == len(whole) - 5000
    assert rrd_files.verify(tmp_path / "fixed.rrd", rerun=rerun_cli())[0]
    res = view("--repair", str(cut))  # default name, text
    assert res.returncode == 0 and res.stdout.startswith(f"repaired {cut} (")
    assert f"chunks recovered into {tmp_path / 'cut.repaired.rrd'}" in res.stdout
    assert rrd_files.verify(tmp_path / "cut.repaired.rrd", rerun=rerun_cli())[0]
    (tmp_path / "head.rrd").write_bytes(whole[:200])
    res = view("--repair", str(tmp_path / "head.rrd"))
    assert res.returncode == 2 and "no complete chunk could be read from" in res.stderr and "200 bytes" in res.stderr


@pytest.mark.needs("vulkan")
def test_screenshot_renders_every_segment_as_one_recording(tmp_path: Path) -> None:
    """Eight segments, one update each: the R² history spans all of them (a rising line), not the last one only."""
    from PIL import Image

    base = tmp_path / "s.rrd"
    files = segments(base, n=8)
    png = tmp_path / "out" / "s.png"
    res = view(str(base), "--screenshot", str(png), "--json", "--timeout", "60")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == {"files": files, "no_footer": [], "empty": [], "screenshot": str(png)}
    img = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    h, w = img.shape[:2]
    assert w == 1280 * h // 800
    panel = img[h * 53 // 100: h * 75 // 100, w * 26 // 100: w * 49 // 100]  # "R² (validation) across updates"
    orange = np.all(np.abs(panel - np.array((250, 140, 40))) < 40, axis=2)  # R² free run
    rows, cols = np.nonzero(orange)
    assert rows.size > 100 and rows.max() - rows.min() > panel.shape[0] // 3, (rows.min(), rows.max())
    assert cols.max() - cols.min() > panel.shape[1] // 2  # from the first segment's update to the last
    top = img[: h * 35 // 100]  # the newest update's figures are drawn too
    assert np.all(np.abs(top - np.array((66, 150, 250))) < 40, axis=2).sum() > 200


@pytest.mark.needs("vulkan")
def test_a_stream_of_several_outputs_is_laid_out_across_its_segments(tmp_path: Path) -> None:
    """The daemon's layout grows: a stream's tab when it is declared, an output's tab when its first model comes, so
    a stream of several outputs has a first segment whose blueprint holds none of their tabs. The viewer lays a
    recording out by the first file it opens; opened oldest first, the F-16 log's segments showed its default layout
    (no R² panel where ours has it). ``streamid view`` opens the newest first."""
    from PIL import Image

    import time

    base = tmp_path / "m.rrd"
    viz = Viz(VizSettings(rrd=str(base), rrd_rotate_s=0.3, recording_id="view-mimo"))
    viz.log_event(None, "daemon started: streams (discovering)", t_ns=0)  # as the daemon's first segment
    viz.flush()
    time.sleep(0.7)  # the idle segment is closed: the next one starts with the stream's layout
    viz.add_stream("s")
    for k, out in enumerate(("y1", "y2", "y3")):
        viz.add_stream(f"s/{out}")
        for v in range(1, 3):
            r = report(2 * k + v, n_val=400)
            viz.log_update(dataclasses.replace(r, stream=f"s/{out}", output_name=out,
                                               metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.3 + 0.08 * (2 * k + v)}))
            viz.flush()
        time.sleep(0.35)  # each output's tab in a later segment than the one before
    viz.close()
    files = viz.files
    assert len(files) >= 3, files
    png = tmp_path / "m.png"
    res = view(str(base), "--screenshot", str(png), "--json", "--timeout", "60")
    assert res.returncode == 0, res.stderr
    img = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    h, w = img.shape[:2]
    panel = img[h * 53 // 100: h * 75 // 100, w * 26 // 100: w * 49 // 100]  # "R² (held out)" of the first output
    orange = np.all(np.abs(panel - np.array((250, 140, 40))) < 40, axis=2)  # R² free run
    assert orange.sum() > 100, orange.sum()
