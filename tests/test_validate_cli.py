"""A model judged on data it has never seen: ``streamid identify --validate VAL`` and ``streamid validate MODEL DATA``.

Real CLI processes on real files: a NARX plant estimated on a random input and validated on a chirp (another
excitation), MCAP-free CSVs with a clock, a model-update document as an online identifier publishes it, a real
``.rrd`` read back.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import STREAMID

from streamid.viz.screenshot import rerun_cli

QUICK = ["--paper", "--neurons", "6", "--generations", "20", "--max-lag", "3", "--workers", "1", "--progress", "never"]


def plant(u: np.ndarray) -> np.ndarray:
    y = np.zeros(u.size)
    for t in range(3, u.size):
        y[t] = 0.5 * y[t - 1] + np.sin(2 * u[t - 2]) - 0.3 * u[t - 1] * y[t - 1]
    return y


def write(path: Path, u: np.ndarray, y: np.ndarray, dt_s: float = 0.01, names: str = "time_s,force,pos") -> Path:
    np.savetxt(path, np.column_stack([np.arange(u.size) * dt_s, u, y]), delimiter=",", header=names, comments="",
               fmt="%.12g")
    return path


def estimation_input(n: int = 600) -> np.ndarray:
    return np.random.default_rng(0).uniform(-1, 1, n)


def chirp(n: int = 400) -> np.ndarray:
    t = np.arange(n) / n
    return 0.6 * np.sin(2 * np.pi * (10 + 80 * t) * t)  # a sweep: not the estimation's random steps


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*STREAMID, *args], capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("val")
    ue, uv = estimation_input(), chirp()
    est, val = write(tmp / "est.csv", ue, plant(ue)), write(tmp / "val.csv", uv, plant(uv))
    model, rep = tmp / "m.json", tmp / "r.json"
    p = cli("identify", str(est), "--validate", str(val), "--input", "force", "--output", "pos", *QUICK,
            "--model", str(model), "--report", str(rep))
    assert p.returncode == 0, p.stderr
    judged = cli("validate", str(model), str(val), "--json")  # the figures every test below compares with
    assert judged.returncode == 0, judged.stderr
    return {"tmp": tmp, "est": est, "val": val, "model": model, "report": json.loads(rep.read_text()),
            "stdout": p.stdout, "ue": ue, "uv": uv, "judged": json.loads(judged.stdout)}


def test_identify_takes_the_validation_data_from_the_second_file(fitted: dict) -> None:
    rep, est, val = fitted["report"], fitted["est"], fitted["val"]
    assert rep["data"]["n_est"] == 600 and rep["data"]["n_val"] == 400 and rep["data"]["validation_path"] == str(val)
    assert f"estimation all 600 samples of {est}, validation all 400 of {val}" in fitted["stdout"]
    # the same samples as one file split after the estimation part: the same figures to the last digit
    both = fitted["tmp"] / "both.csv"
    u = np.concatenate([fitted["ue"], fitted["uv"]])
    y = np.concatenate([plant(fitted["ue"]), plant(fitted["uv"])])  # each experiment starts from rest
    write(both, u, y)
    p = cli("identify", str(both), "--est", "600", "--input", "force", "--output", "pos", *QUICK, "--json")
    assert p.returncode == 0, p.stderr
    split = json.loads(p.stdout)
    assert split["runs"][0]["r2"] == rep["runs"][0]["r2"] and split["runs"][0]["lags"] == rep["runs"][0]["lags"]


def test_validate_gives_the_figures_identify_gave_on_the_same_record(fitted: dict) -> None:
    got = fitted["judged"]
    want = fitted["report"]["runs"][0]
    assert got["format"] == "streamid.validate_report/1" and got["n"] == 400
    assert got["r2"]["fr"] == pytest.approx(want["r2"]["fr_val"], abs=1e-12)
    assert got["r2"]["osa"] == pytest.approx(want["r2"]["osa_val"], abs=1e-12)
    assert got["correlation"]["tests"].keys() == want["correlation"]["val"]["tests"].keys()
    for name, t in got["correlation"]["tests"].items():
        assert t["values"] == pytest.approx(want["correlation"]["val"]["tests"][name]["values"], abs=1e-12)
    assert got["model"]["period_ns"] == 10_000_000 and got["data"]["period_ns"] == 10_000_000 and got["notes"] == []
    # the fit and the RMSE from the model's own free run, computed here
    from streamid.model import Model

    m = Model.load(fitted["model"])
    uv, yv = fitted["uv"], plant(fitted["uv"])
    L = m.max_lag
    fr = m.simulate(uv, yv[:L])
    e, c = yv[L:] - fr[L:], yv[L:] - yv[L:].mean()
    assert got["n_scored"] == 400 - L
    assert got["fit_percent"]["fr"] == pytest.approx(100 * (1 - np.linalg.norm(e) / np.linalg.norm(c)), abs=1e-9)
    assert got["rmse"]["fr"] == pytest.approx(float(np.sqrt(np.mean(e**2))), rel=1e-9)
    text = cli("validate", str(fitted["model"]), str(fitted["val"]))
    assert text.returncode == 0, text.stderr
    assert f"free run           {got['r2']['fr']:.5f}" in text.stdout
    assert f"400 samples of force -> pos; R² over the {400 - L} after the first {L}" in text.stdout


def test_validate_maps_columns_and_names_what_it_needs(fitted: dict) -> None:
    renamed = write(fitted["tmp"] / "renamed.csv", fitted["uv"], plant(fitted["uv"]), names="time_s,volts,position")
    p = cli("validate", str(fitted["model"]), str(renamed))
    assert p.returncode == 2 and "unknown column 'force'" in p.stderr and "'volts'" in p.stderr, p.stderr
    assert "the columns default to the model's signal names (force -> pos): map the record's own with --input COL" \
        in p.stderr, p.stderr
    p = cli("validate", str(fitted["model"]), str(renamed), "--input", "volts", "--output", "position", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["r2"] == fitted["judged"]["r2"]
    p = cli("validate", str(fitted["model"]), str(renamed), "--input", "volts", "--output", "position")
    assert "(volts as force, position as pos)" in p.stdout, p.stdout
    p = cli("validate", str(fitted["model"]), str(renamed), "--input", "volts", "--input", "time_s")
    assert p.returncode == 2 and "the model has 1 input(s) ['force']; --input was given 2 time(s)" in p.stderr


def test_another_sample_period_is_refused(fitted: dict) -> None:
    slow = write(fitted["tmp"] / "slow.csv", fitted["uv"], plant(fitted["uv"]), dt_s=0.02)
    p = cli("validate", str(fitted["model"]), str(slow))
    assert p.returncode == 2, p.stdout
    assert "samples every 20 ms but the model was identified at one sample every 10 ms" in p.stderr, p.stderr
    p = cli("identify", str(fitted["est"]), "--validate", str(slow), "--input", "force", "--output", "pos", *QUICK)
    assert p.returncode == 2 and f"the validation file {slow} samples every 20 ms but {fitted['est']} every 10 ms" \
        in p.stderr, p.stderr
    p = cli("identify", str(fitted["est"]), "--validate", str(fitted["val"]), "--est", "100", "--input", "force",
            "--output", "pos", *QUICK)
    assert p.returncode == 2 and "argument --est: not allowed with argument --validate" in p.stderr, p.stderr


def test_min_r2_fr_is_a_gate(fitted: dict) -> None:
    fr = fitted["judged"]["r2"]["fr"]
    above = min(1.0, fr + 1e-4)
    p = cli("validate", str(fitted["model"]), str(fitted["val"]), "--min-r2-fr", f"{above!r}")
    assert p.returncode == 1 and f"FAILED: free-run R² {fr:.5f} < --min-r2-fr" in p.stdout, p.stdout
    p = cli("validate", str(fitted["model"]), str(fitted["val"]), "--min-r2-fr", f"{fr - 1e-4!r}", "--json")
    assert p.returncode == 0 and json.loads(p.stdout)["passed"] is True
    p = cli("validate", str(fitted["model"]), str(fitted["val"]), "--min-r2-fr", "2")
    assert p.returncode == 2 and "--min-r2-fr must be a finite number <= 1 (an R²); got 2.0" in p.stderr


def test_a_record_beyond_the_estimation_range_is_named(fitted: dict) -> None:
    wide_u = 3.0 * fitted["uv"]
    wide = write(fitted["tmp"] / "wide.csv", wide_u, plant(wide_u))
    got = json.loads(cli("validate", str(fitted["model"]), str(wide), "--json").stdout)
    assert any(c.startswith("the validation input force spans [-1.8") for c in got["caveats"]), got["caveats"]
    inside = fitted["judged"]["caveats"]
    assert not any("beyond the estimation range" in c for c in inside), inside


def test_a_published_model_update_is_judged_like_a_model_file(tmp_path: Path) -> None:
    """The document a subscriber receives from the daemon, saved as it came, judged on a later record."""
    from streamid import OnlineIdentifier, StreamConfig
    from streamid.engine import assess
    from streamid.sim import get_device
    from streamid.transport.updates import parse_model_update

    dev = get_device("mr_damper")
    t, u, y = dev.simulate_seconds(6.0, seed=3)
    cfg = StreamConfig(window_s=2.0, update_every_s=2.0, cold_generations=30, warm_generations=10, neurons=6,
                       max_lag_y=3, max_lag_u=3)
    ident = OnlineIdentifier(cfg, stream="damper")
    ident.learn_many(t, u, y, inputs=[dev.input_name], outputs=[dev.output_name])
    ups = [x for x in ident.update_all() if x.accepted]
    assert ups and ups[-1].payload is not None
    doc = tmp_path / "update.json"
    doc.write_bytes(ups[-1].payload)
    later = tmp_path / "later.csv"  # another record of the device, 200 Hz like the stream
    t2, u2, y2 = dev.simulate_seconds(5.0, seed=7)
    np.savetxt(later, np.column_stack([t2 / 1e9, u2, y2]), delimiter=",", comments="", fmt="%.12g",
               header=f"time_s,{dev.input_name},{dev.output_name}")
    p = cli("validate", str(doc), str(later), "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    model = parse_model_update(ups[-1].payload).model
    want = assess(model, u2, y2)
    assert got["r2"]["fr"] == pytest.approx(want.fr, abs=1e-9) and got["r2"]["osa"] == pytest.approx(want.osa, abs=1e-9)
    assert got["model"]["period_ns"] == 5_000_000 and got["notes"] == []  # the stream's period, checked


def test_validate_draws_the_record_in_rerun(fitted: dict) -> None:
    from test_identify_rrd import column

    rrd = fitted["tmp"] / "v.rrd"
    p = cli("validate", str(fitted["model"]), str(fitted["val"]), "--rrd", str(rrd), "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got["rrd"] == [str(rrd)]
    v = subprocess.run([rerun_cli(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 0 and "1 file verified without error" in v.stdout + v.stderr, v.stdout + v.stderr
    measured = column(rrd, "/streams/val/validation/measured", "Scalars:scalars")
    assert len(measured) == 400  # the whole record is the validation part
    (doc,) = column(rrd, "/streams/val/model", "TextDocument:text")
    assert f"FR **{got['r2']['fr']:.4f}**" in doc[0]  # type: ignore[index]
    assert "the model judged on this record (no identification ran)" in doc[0]  # type: ignore[index]
    events = [t[0] for t in column(rrd, "/streams/val/events", "TextLog:text")]  # type: ignore[index]
    assert any(e.startswith("the model judged on this record: R² val OSA") for e in events), events
    assert not column(rrd, "/streams/val/history/identification_s", "Scalars:scalars")  # no identification ran


def test_reports_write_a_diverged_free_run_as_null() -> None:
    """JSON has no inf or nan: a free run that diverged (R² -inf) is written as null by every command's report."""
    from streamid.commands.identify_io import json_safe

    doc = json_safe({"r2": {"fr": -np.inf, "osa": 0.5}, "runs": [(np.nan, 1.0)], "n": 3})
    assert doc == {"r2": {"fr": None, "osa": 0.5}, "runs": [[None, 1.0]], "n": 3}
    json.dumps(doc, allow_nan=False)


def test_start_and_end_judge_a_part_of_a_log(tmp_path: Path) -> None:
    """The bundled MR damper log: a model fitted on its first 10 s, judged from 10 s on, gives identify's figures."""
    model = tmp_path / "mr.json"
    p = cli("identify", "mr_damper", "--est", "2000", "--model", str(model), *QUICK, "--json")
    assert p.returncode == 0, p.stderr
    want = json.loads(p.stdout)["runs"][0]["r2"]
    p = cli("validate", str(model), "mr_damper", "--start", "10", "--json")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got["r2"] == {"osa": want["osa_val"], "fr": want["fr_val"]} and got["n"] == 1499  # the same free run
    assert got["data"]["span"] == "rows 2000..3498 (10-17.49 s) of 3499" and got["notes"] == []
    whole = json.loads(cli("validate", str(model), "mr_damper", "--json").stdout)  # the fitted rows included
    assert whole["notes"] == ["2000 of the samples judged are ones the model was fitted on (rows 0..1999 of "
                              "mr_damper.mcap): these figures are not all on data it never saw (--start past them)"]
    p = cli("validate", str(model), "mr_damper", "--start", "10", "--end", "12")
    assert p.returncode == 0 and "401 samples of velocity_cm_s -> force_N, rows 2000..2400 (10-12 s) of 3499" in p.stdout
    p = cli("validate", str(model), "mr_damper", "--start", "20")
    assert p.returncode == 2 and "has no sample between --start and --end: it spans 17.49 s" in p.stderr, p.stderr
    p = cli("validate", str(model), "mr_damper", "--start", "6", "--end", "5")
    assert p.returncode == 2 and "--end must be later than --start; got --start 6 --end 5" in p.stderr, p.stderr
    bare = tmp_path / "bare.csv"  # no clock, and a model from a file without one: no times to cut at
    bare.write_text("force,pos\n" + "\n".join(f"{np.sin(k / 7):.6f},{np.cos(k / 5):.6f}" for k in range(200)) + "\n")
    arm = tmp_path / "arm.json"
    q = cli("identify", str(bare), "--input", "force", "--output", "pos", "--model", str(arm), *QUICK)
    assert q.returncode == 0, q.stderr
    q = cli("validate", str(arm), str(bare), "--start", "1")
    assert q.returncode == 2 and "has no clock and the model records no sample period: --start/--end need times" \
        in q.stderr, q.stderr
