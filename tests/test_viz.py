"""Rerun diagnostics: real .rrd files read back, real gRPC servers, viewers that vanish."""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import free_tcp_port

from streamid.errors import ConfigError
from streamid.viz import CorrelationCurve, UpdateReport, Viz, VizSettings, parse_rerun_url

RERUN = str(Path(sys.executable).parent / "rerun")
#: the viewer/server binary itself (the ``rerun`` script forks it: terminate the binary, not the wrapper)
RERUN_BIN = str(Path(__import__("rerun_cli").__file__).parent / "rerun")
P = 5_000_000


def report(version: int, n_val: int = 60) -> UpdateReport:
    rng = np.random.default_rng(version)
    end = 10**9 * (version + 2)
    t0 = end - (n_val - 1) * P
    u = np.sin(np.arange(n_val) * 0.2)
    y = np.tanh(u) + 0.01 * rng.normal(size=n_val)
    lags = np.arange(0, 11)
    corr = tuple(
        CorrelationCurve(k, k, lags, np.r_[1.0, 0.05 * rng.normal(size=10)], 1.96 / np.sqrt(n_val))
        for k in ("ee", "ue", "e_eu", "u2_e", "u2_e2")
    )
    return UpdateReport(
        stream="s", version=version, accepted=True, warm=version > 1, generations=10, window_t0_ns=t0 - 100 * P,
        window_end_ns=end, period_ns=P, val_t0_ns=t0, y_val=y, osa_val=y + 0.01, fr_val=y * 0.98, u_val=u,
        input_name="v", output_name="f", fitness=np.linspace(2, 1, 10), correlations=corr,
        lags={"y": [1], "u": [[1, 2]]}, metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.9}, identification_s=0.1,
        latency_s=0.12,
    )


def test_rrd_file_holds_every_diagnostic_and_verifies(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    rrd = tmp_path / "v.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("s", validation_span_s=0.3)
    for v in (1, 2, 3):
        viz.log_update(report(v))
    viz.log_event("s", "gap of 3 samples", level="WARN", t_ns=3 * 10**9)
    viz.close()
    out = subprocess.run([RERUN, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert "1 file verified without error" in out.stdout + out.stderr
    chunks = RrdReader(rrd).stream().filter(content="/streams/s/**").to_chunks()
    paths = {c.entity_path for c in chunks}
    for p in ("validation/measured", "validation/osa", "validation/free_run", "residual/osa", "residual/free_run",
              "correlation/ee/value", "correlation/ee/band", "correlation/u2_e2/band_low", "fitness",
              "history/r2_osa", "history/r2_fr", "history/identification_s", "history/latency_s",
              "hysteresis/measured", "hysteresis/simulated", "model", "events"):
        assert f"/streams/s/{p}" in paths, p
    resid = [c.to_record_batch() for c in chunks if c.entity_path == "/streams/s/residual/osa" and not c.is_static]
    vals = np.concatenate([np.asarray(rb.column("Scalars:scalars").to_pylist(), dtype=float).ravel() for rb in resid])
    assert vals.size == 3 * 60 and np.allclose(vals, -0.01)  # measured minus OSA, every update
    texts = [rb.column("TextLog:text").to_pylist() for c in chunks if c.entity_path == "/streams/s/events"
             for rb in [c.to_record_batch()]]
    flat = [t for col in texts for row in col for t in (row if isinstance(row, list) else [row])]
    assert any("gap of 3 samples" in t for t in flat) and any("model v3 published" in t for t in flat)
    assert RrdReader(rrd).blueprints()  # the layout is in the file


def test_absent_viewer_is_reported_once_and_costs_nothing(caplog: pytest.LogCaptureFixture, tmp_path: Path) -> None:
    port = free_tcp_port()  # nothing listens there
    caplog.set_level(logging.WARNING, logger="streamid.viz")
    viz = Viz(VizSettings(connect=f"rerun+http://127.0.0.1:{port}/proxy", rrd=str(tmp_path / "f.rrd"), probe_every_s=0.05))
    viz.add_stream("s")
    for v in range(1, 6):
        viz.log_update(report(v))
        time.sleep(0.06)
    t0 = time.monotonic()
    viz.close()
    assert time.monotonic() - t0 < 1.5
    warnings = [r.message for r in caplog.records if "no rerun viewer" in r.message]
    assert len(warnings) == 1 and str(port) in warnings[0]
    assert (tmp_path / "f.rrd").stat().st_size > 0  # the file sink went on


def test_viewer_that_goes_away_is_dropped_with_one_warning(caplog: pytest.LogCaptureFixture) -> None:
    port = free_tcp_port()
    server = subprocess.Popen([RERUN_BIN, "--serve-grpc", "--port", str(port), "--bind", "127.0.0.1"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                time.sleep(0.1)
        caplog.set_level(logging.INFO, logger="streamid.viz")
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
    t0 = time.monotonic()
    viz.close()
    assert time.monotonic() - t0 < 1.5


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
    viz.add_stream("s", validation_span_s=1.0)
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
