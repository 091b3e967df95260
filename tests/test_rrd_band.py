"""The free run's band in Rerun: ``streamid identify --rrd`` and the daemon's diagnostics draw the model's 90 %
prediction interval around the free run on the validation part (scalars ``validation/lower`` and ``/upper``, and
the band in the validation figure), read back from real .rrd files; a model without an interval draws none."""

from __future__ import annotations

import re
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from conftest import STREAMID, endpoint
from test_identify_rrd import column, narx_csv
from streamid.daemon.config import DaemonConfig, StreamConfig
from streamid.daemon.service import Daemon
from streamid.model import Model
from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber
from streamid.transport.updates import ModelUpdate
from streamid.viz.rerun_view import Viz, VizSettings
from streamid.wire.codec import SampleBatch, encode

QUICK = ["--neurons", "6", "--generations", "20", "--max-lag", "3", "--workers", "1", "--progress", "never"]


def test_identify_draws_the_band_the_model_file_gives(tmp_path: Path) -> None:
    data, rrd, model_file = tmp_path / "damper.csv", tmp_path / "out.rrd", tmp_path / "m.json"
    narx_csv(data)
    p = subprocess.run([*STREAMID, "identify", str(data), "--input", "force", "--output", "pos", *QUICK, "--rrd",
                        str(rrd), "--model", str(model_file)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    model = Model.load(model_file)
    assert model.interval is not None
    rows = np.loadtxt(data, delimiter=",", skiprows=1)
    u_val, y_val = rows[300:, 1], rows[300:, 2]  # the validation part: the second half
    band = model.simulate(u_val, y_val[: model.max_lag], interval=0.9)
    base = "/streams/damper/validation"
    got = {k: np.array(column(rrd, f"{base}/{k}", "Scalars:scalars"), dtype=float).ravel()
           for k in ("free_run", "lower", "upper")}
    span = float(np.ptp(y_val))
    for k, want in (("free_run", band.y), ("lower", band.lower), ("upper", band.upper)):
        assert got[k].shape == (300,) and np.max(np.abs(got[k] - want)) <= 1e-9 * span, k
    L = model.max_lag
    assert np.all(got["lower"][L:] < got["free_run"][L:]) and np.all(got["free_run"][L:] < got["upper"][L:])
    # the validation figure holds the band (its edges and fill), and the model text its coverage as identify says it
    for key in ("band_fill", "band_lower", "band_upper"):
        assert column(rrd, f"/streams/damper/plot/validation/{key}", "LineStrips2D:strips"), key
    (doc,) = column(rrd, "/streams/damper/model", "TextDocument:text")
    said = re.search(r"the 90 % free-run band covers ([0-9.]+) % of the validation samples", p.stdout)
    assert said is not None, p.stdout
    assert f"90 % band around the free run: covers **{said.group(1)} %** of the validation samples" in doc[0], doc  # type: ignore[index]


def test_a_model_without_an_interval_draws_no_band(tmp_path: Path) -> None:
    from streamid.engine.validation import validate
    from streamid.viz.identify_report import Clock, draw_identification, identify_update_report

    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, 400)
    y = np.convolve(u, [0.0, 0.5, 0.3], mode="full")[:400]
    data = tmp_path / "d.csv"
    np.savetxt(data, np.column_stack([np.arange(400) * 0.01, u, y]), delimiter=",", header="time_s,force,pos",
               comments="", fmt="%.12g")
    p = subprocess.run([*STREAMID, "identify", str(data), "--input", "force", "--output", "pos", *QUICK, "--model",
                        str(tmp_path / "m.json")], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    bare = replace(Model.load(tmp_path / "m.json"), interval=None)
    rep = validate(bare, u[:200], y[:200], u[200:], y[200:])
    up = identify_update_report("s", bare, rep, u_val=u[200:], y_val=y[200:], n_est=200, clock=Clock.of(None, 10**7),
                                fitness_history=[1.0], generations=1, seconds=0.1)
    assert up.lower_val is None and "interval_coverage_val" not in up.metrics
    rrd = tmp_path / "bare.rrd"
    draw_identification(str(rrd), up)
    assert len(column(rrd, "/streams/s/validation/free_run", "Scalars:scalars")) == 200
    assert column(rrd, "/streams/s/validation/upper", "Scalars:scalars") == []
    assert column(rrd, "/streams/s/plot/validation/band_upper", "LineStrips2D:strips") == []
    (doc,) = column(rrd, "/streams/s/model", "TextDocument:text")
    assert "no prediction interval (the model carries none)" in doc[0]  # type: ignore[index]


def test_the_daemons_diagnostics_draw_the_band_of_each_published_model(tmp_path: Path) -> None:
    ep = endpoint()
    period, n = 5_000_000, 50
    _, u, y = get_device("mr_damper").simulate_seconds(5.0, seed=0)
    cfg = DaemonConfig(streams=("bd",), discover=False, status_every_s=0.2, workers=1, helper=False,
                       retain_memory=False,
                       defaults=StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=20, warm_generations=5,
                                             neurons=4, max_lag_y=2, max_lag_u=2, min_r2_fr=-1e9))
    rrd = tmp_path / "diag.rrd"
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,)), viz=Viz(VizSettings(rrd=str(rrd), rrd_rotate_mb=None))).start()
    ups: list[ModelUpdate] = []
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus, ModelSubscriber(bus, "bd", ups.append) as sub:
            pub = bus.publisher("streamid/bd/samples", block=True)
            assert pub.wait_for_subscribers(10.0)
            for k in range(len(u) // n):
                sl = slice(k * n, (k + 1) * n)
                pub.put(encode(SampleBatch("bd", k, k * n * period, period, None, {"v": u[sl]}, {"f": y[sl]})))
                time.sleep(0.002)
            assert sub.wait_for_version(1, 30.0) is not None, "no model"
            time.sleep(0.3)  # the drawing follows the publication
    finally:
        daemon.stop(timeout_s=2.0)
    first = ups[0]
    assert first.model.interval is not None
    base = "/streams/bd/validation"
    fr, lo, hi = (np.array(column(rrd, f"{base}/{k}", "Scalars:scalars"), dtype=float).ravel()
                  for k in ("free_run", "lower", "upper"))
    n_val = first.window["n_validation"]
    assert lo.shape == hi.shape == fr.shape and len(fr) >= n_val  # one validation part per published model
    L = first.model.max_lag
    part = slice(L, n_val)  # the first model's validation part (drawn first), past its initial outputs
    assert np.all(lo[part] < fr[part]) and np.all(fr[part] < hi[part])
    q, scale = first.model.interval.quantile(0.9), first.model.interval.scale
    assert np.all(hi[part] - lo[part] >= 2 * q * scale * (1 - 1e-9))  # at least q * scale either side
    assert column(rrd, "/streams/bd/plot/validation/band_upper", "LineStrips2D:strips")
    docs = column(rrd, "/streams/bd/model", "TextDocument:text")
    assert any("90 % band around the free run: covers **" in d[0] for d in docs), docs  # type: ignore[index]
