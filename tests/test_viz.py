"""Rerun diagnostics: real .rrd files read back, real gRPC servers, viewers that vanish."""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import free_tcp_port, rerun_grpc_server

from streamid.errors import ConfigError
from streamid.engine.validation import CorrelationTest
from streamid.viz.rerun_view import UpdateReport, Viz, VizSettings, parse_rerun_url, screenshot
from streamid.viz.figures import CANVAS, Axis, Series, figure, fitness_figure, log_ticks, nice_ticks, tick_text

RERUN = str(Path(sys.executable).parent / "rerun")
#: the viewer/server binary itself (the ``rerun`` script forks it: terminate the binary, not the wrapper)
P = 5_000_000


def report(version: int, n_val: int = 60, *, stream: str = "s", end_offset_ns: int = 0) -> UpdateReport:
    """Update ``version`` of ``stream`` (cold for v1 with 10 generations, then warm with 5), window end at v+2 s."""
    rng = np.random.default_rng(version)
    end = 10**9 * (version + 2) + end_offset_ns
    t0 = end - (n_val - 1) * P
    u = np.sin(np.arange(n_val) * 0.2)
    y = np.tanh(u) + 0.01 * rng.normal(size=n_val)
    lags = np.arange(0, 11)
    corr = tuple(
        CorrelationTest(k, k, tuple(lags.tolist()), tuple(np.r_[1.0, 0.05 * rng.normal(size=10)].tolist()), 1.96 / np.sqrt(n_val))
        for k in ("ee", "ue", "e_eu", "u2_e", "u2_e2")
    )
    gens = 10 if version == 1 else 5
    return UpdateReport(
        stream=stream, version=version, accepted=True, warm=version > 1, generations=gens, window_t0_ns=t0 - 100 * P,
        window_end_ns=end, period_ns=P, val_t0_ns=t0, y_val=y, osa_val=y + 0.01, fr_val=y * 0.98, u_val=u,
        input_name="v", output_name="f", fitness=np.geomspace(2.0 / version, 1.0 / version, gens), correlations=corr,
        lags={"y": [1], "u": [[1, 2]]}, metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.9}, identification_s=0.1,
        latency_s=0.12,
    )


def _latest(chunks: list, path: str, column: str) -> object:
    """The value of ``column`` in the row of ``path`` with the greatest stream time (a latest-at query at the end)."""
    rows = []
    for c in chunks:
        if c.entity_path != path or c.is_static:
            continue
        rb = c.to_record_batch()
        if column not in rb.schema.names:
            continue
        for t, v in zip(rb.column("stream_time").to_pylist(), rb.column(column).to_pylist()):
            if v is not None:
                rows.append((t, v))
    assert rows, f"{path} has no {column}"
    return max(rows, key=lambda r: r[0])[1]


def test_rrd_file_holds_every_diagnostic_and_verifies(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    rrd = tmp_path / "v.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("s")
    reports = [report(v) for v in (1, 2, 3)]
    for r in reports:
        viz.log_update(r)
    viz.log_event("s", "gap of 3 samples", level="WARN", t_ns=3 * 10**9)
    viz.close()
    out = subprocess.run([RERUN, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert "1 file verified without error" in out.stdout + out.stderr
    chunks = RrdReader(rrd).stream().filter(content="/streams/s/**").to_chunks()
    paths = {c.entity_path for c in chunks}
    for p in ("validation/measured", "validation/osa", "validation/free_run", "residual/osa", "residual/free_run",
              "correlation/ee/value", "correlation/ee/outside", "correlation/ee/band", "correlation/u2_e2/band_low",
              "fitness", "history/r2_osa", "history/r2_fr", "history/identification_s", "history/latency_s",
              "plot/validation/measured", "plot/validation/osa", "plot/validation/free_run", "plot/validation/labels",
              "plot/residual/osa", "plot/residual/free_run", "plot/fitness/cold", "plot/fitness/newest",
              "hysteresis/measured", "hysteresis/simulated", "hysteresis/frame", "model", "events"):
        assert f"/streams/s/{p}" in paths, p
    resid = [c.to_record_batch() for c in chunks if c.entity_path == "/streams/s/residual/osa" and not c.is_static]
    vals = np.concatenate([np.asarray(rb.column("Scalars:scalars").to_pylist(), dtype=float).ravel() for rb in resid])
    assert vals.size == 3 * 60 and np.allclose(vals, -0.01)  # measured minus OSA, every update
    texts = [rb.column("TextLog:text").to_pylist() for c in chunks if c.entity_path == "/streams/s/events"
             for rb in [c.to_record_batch()]]
    flat = [t for col in texts for row in col for t in (row if isinstance(row, list) else [row])]
    assert any("gap of 3 samples" in t for t in flat) and any("model v3 published" in t for t in flat)
    assert RrdReader(rrd).blueprints()  # the layout is in the file

    # the newest update's figures: every point of the validation part, inside the canvas
    w, h = CANVAS["validation"]
    (strip,) = _latest(chunks, "/streams/s/plot/validation/measured", "LineStrips2D:strips")
    xy = np.asarray(strip, dtype=float)
    assert xy.shape == (60, 2) and np.all((xy >= 0) & (xy <= [w, h]))
    assert np.all(np.diff(xy[:, 0]) > 0)  # time runs to the right
    legend = _latest(chunks, "/streams/s/plot/validation/labels", "Points2D:labels")
    assert "one step ahead  R² 0.9900" in legend and "free run  R² 0.9000" in legend
    # fitness: the warm v3 is drawn after the cold run v1 (10 + 5 generations)
    (cold,) = _latest(chunks, "/streams/s/plot/fitness/cold", "LineStrips2D:strips")
    (newest,) = _latest(chunks, "/streams/s/plot/fitness/newest", "LineStrips2D:strips")
    assert len(cold) == 10 and len(newest) == 5
    assert min(p[0] for p in newest) > max(p[0] for p in cold)
    assert "cold v1" in _latest(chunks, "/streams/s/plot/fitness/labels", "Points2D:labels")
    # correlation tests: the values outside the ±95 % band are drawn again, in red
    ee = next(c for c in reports[-1].correlations if c.name == "ee")
    outside = _latest(chunks, "/streams/s/correlation/ee/outside", "BarChart:values")[0]["buffer"]
    expected = np.where(np.abs(ee.values) > ee.band, ee.values, 0.0)
    assert np.allclose(outside, expected) and np.count_nonzero(expected) >= 1  # lag 0 (= 1.0) at least
    model = _latest(chunks, "/streams/s/model", "TextDocument:text")
    assert "v3" in model[0] and "f(t) = F[f(t-1) v(t-1,t-2)]" in model[0]  # the one lag vocabulary
    assert f"ee FAIL: lag 0 value 1 outside ±{ee.strict_band:.3g} (99.9 % band)" in model[0]  # the reason of a failure


def _blueprint_rows(rrd: Path) -> dict[str, dict[str, object]]:
    """The fullest blueprint of ``rrd``: entity path -> {component: value}.

    The daemon sends a new blueprint when a stream is added, each in its own
    store with a random id, so ``RrdReader.blueprints()`` does not list them in
    sending order; the newest one is the one laying out the most containers and views.
    """
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    best: dict[str, dict[str, object]] = {}
    for store in reader.blueprints():
        out: dict[str, dict[str, object]] = {}
        for c in reader.stream(store=store).to_chunks():
            rb = c.to_record_batch()
            for name in rb.schema.names:
                if ":" in name:
                    col = [v for v in rb.column(name).to_pylist() if v is not None]
                    if col:  # a batch of one value is that value
                        v = col[-1]
                        out.setdefault(c.entity_path, {})[name] = v[0] if isinstance(v, list) and len(v) == 1 else v
        if len(out) > len(best):
            best = out
    return best


def test_blueprint_shows_each_streams_newest_update_wherever_the_cursor_is(tmp_path: Path) -> None:
    """Two streams on different clocks: no view depends on a time range around the (shared) cursor."""
    rrd = tmp_path / "two.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("early")  # declared first: the first tab, although its clock ends 100 s before the other's
    viz.add_stream("late")
    for v in (1, 2):
        viz.log_update(report(v, stream="early"))
        viz.log_update(report(v, stream="late", end_offset_ns=100 * 10**9))
    viz.close()
    bp = _blueprint_rows(rrd)
    comps = {k for row in bp.values() for k in row}
    assert not any(k.startswith("VisibleTimeRanges") for k in comps)  # no cursor-relative (or any) range
    assert bp["/time_panel"]["TimePanelBlueprint:play_state"] is not None
    assert bp["/time_panel"]["TimePanelBlueprint:timeline"] == "stream_time"
    tabs = next(row for row in bp.values() if "ContainerBlueprint:active_tab" in row)
    names = [bp[f"/{c}"]["ContainerBlueprint:display_name"] for c in tabs["ContainerBlueprint:contents"]]
    assert names == ["early", "late"]
    views = {row["ViewBlueprint:space_origin"]: (row["ViewBlueprint:class_identifier"], path)
             for path, row in bp.items() if "ViewBlueprint:space_origin" in row}
    for sub in ("plot/validation", "plot/residual", "plot/fitness", "hysteresis"):
        cls, path = views[f"streams/early/{sub}"]
        assert cls == "2D"  # latest-at: shows the newest update at or before the cursor
        assert bp[f"{path}/VisualBounds2D"]["VisualBounds2D:range"] is not None


def test_a_stream_with_several_outputs_opens_on_its_first_outputs_tab(tmp_path: Path) -> None:
    """A configured MIMO stream has its own tab from the start (events only) and a tab per output: the viewer opens on
    the first output's, not on the empty one (seen in an F-16 daemon's .rrd, 2026-11-26)."""
    rrd = tmp_path / "mimo.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("f16")  # configured: declared at the daemon's start
    for out in ("a1", "a2"):
        viz.add_stream(f"f16/{out}")
        viz.log_update(report(1, stream=f"f16/{out}"))
    viz.close()
    bp = _blueprint_rows(rrd)
    tabs = next(row for row in bp.values() if "ContainerBlueprint:active_tab" in row)
    names = [bp[f"/{c}"]["ContainerBlueprint:display_name"] for c in tabs["ContainerBlueprint:contents"]]
    assert names == ["f16", "f16/a1", "f16/a2"]
    active = tabs["ContainerBlueprint:active_tab"]
    assert bp[f"/{active}"]["ContainerBlueprint:display_name"] == "f16/a1", active


@pytest.mark.needs("vulkan")
def test_screenshot_by_the_real_viewer_shows_the_first_tabs_newest_update(tmp_path: Path) -> None:
    """The real viewer, headless: the recording ends 100 s after the first tab's stream; its figures are drawn."""
    from PIL import Image

    rrd = tmp_path / "shot.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("early")
    viz.add_stream("late")
    for v in (1, 2):
        viz.log_update(report(v, stream="early"))
        viz.log_update(report(v, stream="late", end_offset_ns=100 * 10**9))
    viz.close()
    png = tmp_path / "out" / "shot.png"
    assert screenshot(rrd, png, window_size="1280x800", timeout_s=60, settle_s=0.0) == png
    img = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    assert img.shape[1] == 1280 * img.shape[0] // 800
    top = img[: img.shape[0] * 35 // 100]  # the validation and residual figures
    for colour in ((66, 150, 250), (250, 140, 40)):  # one step ahead, free run
        near = np.all(np.abs(top - np.array(colour)) < 40, axis=2)
        assert near.sum() > 200, colour
    with pytest.raises(FileNotFoundError, match="no .rrd file"):
        screenshot(tmp_path / "missing.rrd", png)
    with pytest.raises(ConfigError, match="WIDTHxHEIGHT"):
        screenshot(rrd, png, window_size="big")


def test_figure_ticks_labels_and_clipping() -> None:
    t = nice_ticks(-1.23, 0.04)
    assert np.all((t >= -1.23) & (t <= 0.04)) and len(t) >= 2 and 0.0 in t
    assert list(nice_ticks(0, 430.5)) == [0, 100, 200, 300, 400]
    assert list(log_ticks(4.9, 1200)) == [10, 100, 1000]
    assert tick_text(-0.5, np.array([-1.0, -0.5, 0.0])) == "−0.5"
    x = np.linspace(0, 1, 50)
    y = np.sin(6 * x)
    y[20] = np.nan
    wild = 1e6 * x  # a diverging free run
    fig = figure([Series("a", "measured", (1, 2, 3), x, y), Series("b", "free run", (4, 5, 6), x, wild)],
                 kind="validation", x=Axis(0, 1), y=Axis(-1.2, 1.2), x_unit="s", note="[f] · window end 1.000 s")
    x0, y0, x1, y1 = fig.frame
    strips = dict((k, st) for k, _, _, st in fig.lines)
    assert [len(p) for p in strips["a"]] == [20, 29]  # broken at the NaN
    for pts in (*strips["a"], *strips["b"]):
        assert np.all((pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1))
    texts = [la.text for la in fig.labels]
    assert "1.0 s" in texts and "measured" in texts and "[f] · window end 1.000 s" in texts
    boxes = sorted((la.x - (7.4 * len(la.text) + 16) / 2, la.x + (7.4 * len(la.text) + 16) / 2)
                   for la in fig.labels if la.y > y1)  # x tick labels do not overlap
    assert all(a[1] <= b[0] for a, b in zip(boxes, boxes[1:]))
    f = fitness_figure((7, True, np.geomspace(5.2, 5.1, 30)), (1, np.geomspace(900, 5.0, 400)))
    keys = [k for k, _, _, _ in f.lines]
    assert keys == ["cold", "newest"] and any(la.text == "warm" for la in f.labels)
    (cold,) = dict((k, st) for k, _, _, st in f.lines)["cold"]
    assert cold[0, 1] < cold[-1, 1]  # log axis, y downwards: the first generation is the highest
    solo = fitness_figure((1, False, np.geomspace(900, 5.0, 400)), None)
    assert [k for k, _, _, _ in solo.lines] == ["newest"]


def test_absent_viewer_is_reported_once_and_costs_nothing(caplog: pytest.LogCaptureFixture, tmp_path: Path) -> None:
    port = free_tcp_port()  # nothing listens there
    caplog.set_level(logging.WARNING, logger="streamid.viz.rerun_view")
    viz = Viz(VizSettings(connect=f"rerun+http://127.0.0.1:{port}/proxy", rrd=str(tmp_path / "f.rrd"), probe_every_s=0.05))
    viz.add_stream("s")
    for v in range(1, 6):
        viz.log_update(report(v))
        time.sleep(0.06)
    viz.close()
    assert viz._closed  # noqa: SLF001 - closed (its time is the bench's figure, not a test's)
    warnings = [r.message for r in caplog.records if "no rerun viewer" in r.message]
    assert len(warnings) == 1 and str(port) in warnings[0]
    assert (tmp_path / "f.rrd").stat().st_size > 0  # the file sink went on


def test_viewer_that_goes_away_is_dropped_with_one_warning(caplog: pytest.LogCaptureFixture) -> None:
    port = free_tcp_port()
    server = rerun_grpc_server(port)
    try:
        caplog.set_level(logging.INFO, logger="streamid.viz.rerun_view")
        viz = Viz(VizSettings(connect=f"rerun+http://127.0.0.1:{port}/proxy", probe_every_s=0.05))
        assert viz._live is not None  # noqa: SLF001 - connected to the real server
        viz.add_stream("s")
        viz.log_update(report(1))
        viz.flush()
    finally:
        server.terminate()
        server.wait(timeout=10)
    for v in range(2, 8):
        time.sleep(0.06)
        viz.log_update(report(v))  # keeps working without the viewer
    assert viz._live is None  # noqa: SLF001
    gone = [r.message for r in caplog.records if "went away" in r.message]
    assert len(gone) == 1
    viz.close()
    assert viz._closed  # noqa: SLF001 - closed (its time is the bench's figure, not a test's)


def test_served_endpoint_binds_loopback_only(tmp_path: Path) -> None:
    port = free_tcp_port()
    viz = Viz(VizSettings(serve_port=port, rrd=str(tmp_path / "s.rrd")))
    try:
        viz.log_update(report(1))
        listening = []
        with open("/proc/net/tcp", encoding="ascii") as fh:
            for line in fh.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                if state == "0A" and int(local.split(":")[1], 16) == port:
                    listening.append(local.split(":")[0])
        assert listening == ["0100007F"]  # 127.0.0.1, not 0.0.0.0
    finally:
        viz.close()


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="rerun\\+http://127.0.0.1:9876/proxy"):
        VizSettings(connect="http://localhost:9876")
    with pytest.raises(ConfigError, match="--rerun-serve must be a TCP port"):
        VizSettings(serve_port=0)
    assert parse_rerun_url("rerun+http://127.0.0.1:9999/proxy") == ("127.0.0.1", 9999)
    assert not VizSettings().enabled
    Viz(VizSettings()).log_update(report(1))  # no sink: a no-op


def test_rrd_rotates_with_footers_and_keeps_the_newest(tmp_path: Path) -> None:
    import dataclasses

    rrd = tmp_path / "rot.rrd"
    viz = Viz(VizSettings(rrd=str(rrd), rrd_rotate_mb=0.05, rrd_keep=2, max_points=500))
    viz.add_stream("s")
    base = report(1, n_val=2000)
    for v in range(1, 25):
        viz.log_update(dataclasses.replace(base, version=v, window_end_ns=10**9 * (v + 20),
                                           val_t0_ns=10**9 * (v + 20) - 1999 * P))
        viz.flush()
    viz.close()
    files = viz.files
    assert len(files) == 2 and files[-1].endswith(".rrd") and ".0" in files[-1]
    assert sorted(str(p) for p in tmp_path.iterdir()) == sorted(files)  # older ones deleted
    for f in files:
        out = subprocess.run([RERUN, "rrd", "verify", f], capture_output=True, text=True, timeout=60)
        assert "1 file verified without error" in out.stdout + out.stderr, f
    from rerun.chunk import RrdReader

    rows = sum(c.num_rows for f in files
               for c in RrdReader(f).stream().filter(content="/streams/s/validation/measured").to_chunks()
               if not c.is_static)
    assert rows > 0 and rows % 500 == 0  # 2000 samples drawn as 500 points per update
    assert RrdReader(files[-1]).blueprints()


def test_the_model_text_says_whether_the_weights_were_refined_and_why() -> None:
    from dataclasses import replace

    from streamid.viz.reports import model_markdown, refinement_text

    made = {"taken": True, "held_out": {"samples": 700, "r2_fr_before": 0.93516, "r2_fr_after": 0.94379}}
    refused = {"taken": False, "reason": "no gain on the held-out second half (free-run R2 0.95317 -> 0.94321 "
                                         "refined on the first)", "held_out": {"samples": 700}}
    text = model_markdown(replace(report(2), refinement=made))
    assert "weights refined to the free run (held-out half FR 0.9352 -> 0.9438)" in text
    assert "weights not refined: no gain on the held-out second half" in model_markdown(replace(report(2),
                                                                                               refinement=refused))
    assert "refined" not in model_markdown(report(2))  # no refinement evidence (e.g. --paper): nothing said
    assert refinement_text({"taken": True, "held_out": "x"}) == (
        "weights refined to the free run (held-out half FR n/a -> n/a)")
    assert refinement_text({"taken": False}) == "" and refinement_text("odd") == ""  # type: ignore[arg-type]
