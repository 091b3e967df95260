"""``streamid identify --rrd FILE``: the result drawn in the daemon's Rerun layout, read back, verified, rendered."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import STREAMID

from streamid.viz.screenshot import rerun_cli

QUICK = ["--paper", "--neurons", "6", "--generations", "20", "--max-lag", "3", "--workers", "1", "--progress", "never"]


def narx_csv(path: Path, n: int = 600) -> None:
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(3, n):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    np.savetxt(path, np.column_stack([np.arange(n) * 0.01, u, y]), delimiter=",", header="time_s,force,pos",
               comments="", fmt="%.12g")


def identify(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, "identify", *args], capture_output=True, text=True, timeout=120)


def column(rrd: Path, entity: str, name: str) -> list[object]:
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    (entry,) = reader.recordings()
    out: list[object] = []
    for chunk in reader.stream(store=entry).filter(content=entity).to_chunks():
        batch = chunk.to_record_batch()
        if name in batch.schema.names:
            out += batch.column(name).to_pylist()
    return out


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, str]:
    tmp = tmp_path_factory.mktemp("rrd")
    data, rrd, rep = tmp / "damper.csv", tmp / "out.rrd", tmp / "r.json"
    narx_csv(data)
    p = identify(str(data), "--input", "force", "--output", "pos", *QUICK, "--rrd", str(rrd), "--report", str(rep))
    assert p.returncode == 0, p.stderr
    assert f"rrd: {rrd} (streamid view {rrd}; --screenshot PNG renders it)" in p.stdout
    return rrd, json.loads(rep.read_text()), p.stdout


def test_rrd_verifies_and_holds_the_kept_model(drawn: tuple[Path, dict, str]) -> None:
    rrd, rep, _ = drawn
    assert rep["rrd"] == [str(rrd)]
    v = subprocess.run([rerun_cli(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 0 and "1 file verified without error" in v.stdout + v.stderr, v.stdout + v.stderr
    r2 = rep["runs"][0]["r2"]
    (doc,) = column(rrd, "/streams/damper/model", "TextDocument:text")
    assert isinstance(doc, list) and len(doc) == 1
    text = doc[0]
    assert f"FR **{r2['fr_val']:.4f}**" in text and f"OSA **{r2['osa_val']:.4f}**" in text, text
    assert "model: pos(t) = F[pos(t-1" in text and "correlation tests (validation residual):" in text
    assert "refined" not in text  # --paper never refines: the text says nothing of it
    events = [t[0] for t in column(rrd, "/streams/damper/events", "TextLog:text")]  # type: ignore[index]
    assert any("read: 600 rows; comma-separated, decimal point, clock 'time_s' (period 10 ms)" in e for e in events)
    assert any(e.startswith("run 0 (seed 0) kept:") and f"FR {r2['fr_val']:.4f}" in e for e in events), events
    times = column(rrd, "/streams/damper/validation/measured", "stream_time")
    measured = column(rrd, "/streams/damper/validation/measured", "Scalars:scalars")
    assert len(measured) == rep["data"]["n_val"] == 300  # the validation part, on the file's clock
    first = min(int(np.timedelta64(t, "ns").astype(np.int64)) for t in times)  # type: ignore[call-overload]
    assert first == 300 * 10_000_000  # the first validation sample: 3 s after the first sample


def test_rrd_model_text_says_what_the_refinement_did(tmp_path: Path) -> None:
    from streamid.viz.reports import refinement_text

    data, rrd, model = tmp_path / "damper.csv", tmp_path / "out.rrd", tmp_path / "m.json"
    narx_csv(data)
    small = ["--neurons", "6", "--generations", "20", "--max-lag", "3", "--runs", "1", "--workers", "1",
             "--progress", "never"]  # not --paper: the kept model's refinement is judged
    p = identify(str(data), "--input", "force", "--output", "pos", *small, "--rrd", str(rrd), "--model", str(model))
    assert p.returncode == 0, p.stderr
    ev = json.loads(model.read_text())["metrics"]["refinement"]
    said = refinement_text(ev)
    assert said.startswith("weights refined to the free run" if ev.get("taken") else "weights not refined: "), said
    (doc,) = column(rrd, "/streams/damper/model", "TextDocument:text")
    assert said in doc[0], doc[0]  # read back from the real .rrd


def test_rrd_target_is_checked_before_identifying(tmp_path: Path) -> None:
    data = tmp_path / "d.csv"
    narx_csv(data, 100)
    p = identify(str(data), "--input", "force", "--output", "pos", *QUICK, "--rrd", str(tmp_path / "out.png"))
    assert p.returncode == 2 and "the file name must end in .rrd" in p.stderr, p.stderr
    missing = tmp_path / "no" / "out.rrd"
    p = identify(str(data), "--input", "force", "--output", "pos", *QUICK, "--rrd", str(missing))
    assert p.returncode == 2 and f"the directory '{missing.parent}' does not exist" in p.stderr, p.stderr


@pytest.mark.needs("vulkan")
def test_streamid_view_renders_the_identify_rrd(drawn: tuple[Path, dict, str], tmp_path: Path) -> None:
    """The real viewer, headless: the validation figure shows the measured output and both predictions."""
    from PIL import Image

    rrd, _, _ = drawn
    png = tmp_path / "identify.png"
    res = subprocess.run([*STREAMID, "view", str(rrd), "--screenshot", str(png), "--timeout", "60"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    img = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    h, w = img.shape[:2]
    assert w == 1280 * h // 800
    top = img[h * 8 // 100: h * 30 // 100, : w * 58 // 100]  # the validation figure
    for rgb in ((66, 150, 250), (250, 140, 40)):  # one step ahead, free run
        assert np.all(np.abs(top - np.array(rgb)) < 40, axis=2).sum() > 200, rgb
    plane = img[h * 53 // 100: h * 75 // 100, w * 78 // 100:]  # the input-output plane: the free run drawn
    assert np.all(np.abs(plane - np.array((250, 140, 40))) < 40, axis=2).sum() > 100
