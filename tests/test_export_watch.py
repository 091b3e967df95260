"""``streamid watch --save-fmu DIR`` with a real daemon (a subprocess on loopback Zenoh) and the MR damper log
replayed onto it: each newly served champion is written as ``<stream>+v<version>.fmu``, the newest also as
``<stream>.fmu``; fmpy (a well-kept FMI library, used only by the tests) finds no problem in them and runs
the newest as the model the watch received."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import STREAMID, endpoint, read_until
from replay.player import ReplayConfig, replay_log
from streamid.model.narx import Model
from streamid.logs import bundled_log
from streamid.transport import ZenohSettings

fmpy = pytest.importorskip("fmpy", reason="needs fmpy (pip install '.[test]')")
from fmpy.validation import validate_fmu  # noqa: E402

CONFIG = """
[defaults]
window_s = 3.0
update_every_s = 1.5
cold_generations = 30
warm_generations = 10
neurons = 6
max_lag_y = 4
max_lag_u = 4
challenger_margin = -1.0  # every valid challenger is served: two versions come quickly
"""


def test_watch_saves_each_served_champion_as_an_fmu(tmp_path: Path) -> None:
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")
    ep = endpoint()
    (tmp_path / "daemon.toml").write_text(CONFIG)
    out = tmp_path / "fmus"
    out.mkdir()
    daemon = subprocess.Popen([*STREAMID, "daemon", "--config", str(tmp_path / "daemon.toml"), "--listen", ep,
                               "--state-dir", str(tmp_path / "state")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    watch = subprocess.Popen([*STREAMID, "watch", "--connect", ep, "--stream", "mr_damper", "--count", "2",
                              "--duration", "90", "--json", "--save-fmu", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready = read_until(watch.stderr, "waiting for models")  # (a client may first say it waits for the daemon)
        assert ready and "waiting for models" in ready[-1], ready
        replay_log(bundled_log("mr_damper.mcap"), ZenohSettings(connect=(ep,)),
                   ReplayConfig(rate=10.0, wait_subscribers_s=15.0))
        wout, werr = watch.communicate(timeout=90)
    finally:
        for p in (watch, daemon):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
    assert watch.returncode == 0, werr
    docs = [json.loads(ln) for ln in wout.splitlines() if ln.startswith("{") and '"streamid.model-update/1"' in ln]
    versions = [d["version"] for d in docs]  # --count 2 stops it: a few more may be delivered while it closes
    assert len(versions) >= 2 and versions == sorted(versions), versions
    files = sorted(p.name for p in out.iterdir())
    kept = versions[-3:]  # --keep 3 (the default): the older versions deleted
    assert files == sorted([*(f"mr_damper+v{v}.fmu" for v in kept), "mr_damper.fmu"]), (files, werr)
    assert f"mr_damper v{versions[-1]} saved as" in werr
    newest = out / f"mr_damper+v{versions[-1]}.fmu"
    assert (out / "mr_damper.fmu").read_bytes() == newest.read_bytes()  # the newest, whole
    for f in out.iterdir():
        assert validate_fmu(str(f)) == [], f
    # the newest FMU runs as the model the watch received (fmpy's loop: no direct terms in these models)
    model = Model.from_dict(docs[-1]["model"])
    assert not any(r.lag == 0 and r.signal == "u" for r in model.regressors)
    log = np.loadtxt(Path(__file__).resolve().parents[1] / "examples" / "data" / "mr_damper.csv", delimiter=",",
                     skiprows=1)[:400]
    u = log[:, 1]
    h = 0.005
    sig = np.zeros(len(u), dtype=[("time", float), (model.input_names[0], float)])
    sig["time"], sig[model.input_names[0]] = np.arange(len(u)) * h, u
    res = fmpy.simulate_fmu(str(out / "mr_damper.fmu"), start_time=0.0, stop_time=(len(u) - 1) * h,
                            output_interval=h, input=sig, fmi_type="CoSimulation")
    mid = 0.5 * (model.normalisation.y_low + model.normalisation.y_high)
    want = model.simulate(u, np.full(model.max_lag, mid))
    span = model.normalisation.y_high - model.normalisation.y_low
    assert np.max(np.abs(res[model.output_name] - want)) <= 1e-6 * span


def test_the_saver_puts_every_output_of_a_stream_in_one_fmu(tmp_path: Path) -> None:
    """The part of ``--save-fmu`` that needs no network, on real parsed model updates of a two-output stream:
    each accepted update makes an FMU of the stream's current model of every output."""
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")
    from fmpy.model_description import read_model_description

    from export_models import kinds, second_output
    from streamid.export.saver import FmuSaver
    from streamid.transport.updates import parse_model_update
    from streamid.wire.documents import encode_json, model_update_message

    def update(model: Model, version: int) -> object:
        return parse_model_update(encode_json(model_update_message(
            stream="rig", version=version, model=model.to_dict(), window={"period_ns": 10_000_000}, metrics={},
            warm=False, generations=1, identification_s=0.1, window_closed_unix_ns=1, published_unix_ns=1,
            output=model.output_name, accepted=True)))

    saver = FmuSaver(str(tmp_path))
    saver.offer(update(kinds()["ensemble"], 1))
    saver.offer(update(second_output(), 2))
    saver.save_pending()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig+v1.fmu", "rig+v2.fmu", "rig.fmu"]
    assert saver.saved == 2
    assert (tmp_path / "rig.fmu").read_bytes() == (tmp_path / "rig+v2.fmu").read_bytes()
    outputs = {1: ["pos_mm", "pos_mm_in_domain"], 2: ["pos_mm", "temp_C", "pos_mm_in_domain", "temp_C_in_domain"]}
    for v, names in outputs.items():
        md = read_model_description(str(tmp_path / f"rig+v{v}.fmu"))
        assert [x.name for x in md.modelVariables if x.causality == "output"] == names
        assert md.coSimulation.modelIdentifier == "rig"  # the same in every version: a rig's reference holds
        assert validate_fmu(str(tmp_path / f"rig+v{v}.fmu")) == []
