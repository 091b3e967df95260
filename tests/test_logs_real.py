"""Bundled real logs equal their sources exactly; simulated device logs are the simulators' output."""

from __future__ import annotations

import subprocess
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat

from conftest import DATA_DIR, STREAMID
from recorders.convert import convert, main as convert_main
from recorders.devices import recorded_devices, simulate_device_log
from streamid import logs as mcaplog
from streamid.errors import ConfigError
from streamid.sim import get_device


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    return [tuple(m) for m in mcaplog.iter_log(path)]


def test_mr_damper_log_equals_magneto_mat_exactly() -> None:
    m = loadmat(str(DATA_DIR / "mr_damper" / "Magneto.mat"))
    v = np.concatenate([m["U"].ravel(), m["U_val"].ravel()])
    f = np.concatenate([m["Y"].ravel(), m["Y_val"].ravel()])
    a = mcaplog.read_log_arrays(mcaplog.bundled_log("mr_damper"))
    assert a.stream == "mr_damper" and len(a) == 3499 and a.period_ns == 5_000_000
    assert list(a.inputs) == ["velocity_cm_s"] and list(a.outputs) == ["force_N"]
    assert a.inputs["velocity_cm_s"].tobytes() == v.astype(np.float64).tobytes()
    assert a.outputs["force_N"].tobytes() == f.astype(np.float64).tobytes()
    assert a.t_ns.tolist() == (5_000_000 * np.arange(3499)).tolist()
    meta = a.metadata["streamid"]
    assert "hibames" in meta["source_repository"] and "licence" in meta


def test_piezo_log_equals_dat_file_exactly() -> None:
    rows = [line.split() for line in (DATA_DIR / "piezo_p885" / "Model_Vi_Do.dat").read_text().splitlines()
            if line.strip()]
    volts = np.array([float(r[0]) for r in rows])  # Python's own decimal -> float64 parse
    disp = np.array([float(r[4]) for r in rows])
    a = mcaplog.read_log_arrays(mcaplog.bundled_log("piezo_p885"))
    assert a.stream == "piezo_p885" and len(a) == 8027 == len(rows)
    assert a.inputs["voltage_V"].tobytes() == volts.tobytes()
    assert a.outputs["displacement_um"].tobytes() == disp.tobytes()
    assert "MIT" in a.metadata["streamid"]["licence"]


@pytest.mark.parametrize(("name", "source"), [("mr_damper", "mr_damper/Magneto.mat"),
                                              ("piezo_p885", "piezo_p885/Model_Vi_Do.dat")])
def test_conversion_is_reproducible(name: str, source: str, tmp_path: Path) -> None:
    out = tmp_path / f"{name}.mcap"
    assert convert_main([name, str(DATA_DIR / source), str(out)]) == 0
    fresh, bundled = _messages(out), _messages(mcaplog.bundled_log(name))
    assert fresh == bundled and len(fresh) > 100


def test_attribution_is_kept_beside_the_data() -> None:
    data = resources.files("streamid") / "data"
    mr = (data / "mr_damper.PROVENANCE.md").read_text(encoding="utf-8")
    pz = (data / "piezo_p885.PROVENANCE.md").read_text(encoding="utf-8")
    assert "No license file in the repository" in mr and "caf1cf628cedad56cd80c1b6cd849422fb42b36d" in mr
    assert "MIT License" in pz and "Yan Naing Aye" in pz
    for sub in ("mr_damper", "piezo_p885"):
        assert (DATA_DIR / sub / "PROVENANCE.md").is_file()


def test_convert_refuses_bad_sources(tmp_path: Path) -> None:
    from streamid.errors import DataError

    bad = tmp_path / "bad.dat"
    bad.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(DataError, match="7 columns"):
        convert("piezo_p885", bad, tmp_path / "o.mcap")
    with pytest.raises(DataError, match="must be one of"):
        convert("nope", bad, tmp_path / "o.mcap")


@pytest.mark.parametrize(("device", "duration_s"), [("reactor", None), ("mr_damper", 5.0), ("piezo", 0.1)])
def test_simulated_device_logs_are_the_seeded_simulation(device: str, duration_s, tmp_path: Path) -> None:
    spec = get_device(device)
    assert recorded_devices()[device] is spec  # one registry: streamid.sim
    a_path, b_path, c_path = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    info = simulate_device_log(device, a_path, seed=3, duration_s=duration_s)
    simulate_device_log(device, b_path, seed=3, duration_s=duration_s)
    simulate_device_log(device, c_path, seed=4, duration_s=duration_s)
    assert _messages(a_path) == _messages(b_path)
    assert _messages(a_path) != _messages(c_path)
    t_ns, u, y = spec.simulate(info["samples"], np.random.default_rng(3))
    a = mcaplog.read_log_arrays(a_path)
    assert a.stream == spec.stream and a.period_ns == spec.period_ns
    assert a.inputs[spec.input_name].tobytes() == np.asarray(u, np.float64).tobytes()
    assert a.outputs[spec.output_name].tobytes() == np.asarray(y, np.float64).tobytes()
    assert a.t_ns.tolist() == np.asarray(t_ns).tolist()
    assert a.metadata["streamid"]["seed"] == "3"


def test_simulate_cli_split_keys(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    res = subprocess.run(STREAMID + ["simulate", "reactor", str(out), "--duration", "20", "--seed", "1",
                                     "--split", "--stream", "r2"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "100 samples at 5 Hz" in res.stdout
    keys = {k for k, _, _ in mcaplog.iter_log(out)}
    assert keys == {"streamid/r2/u", "streamid/r2/y"}
    a = mcaplog.read_log_arrays(out)
    assert len(a) == 100 and list(a.inputs) == ["initiator_flow"]
    with pytest.raises(ConfigError, match="device must be one of"):
        simulate_device_log("toaster", out)
    with pytest.raises(ConfigError, match="duration_s must"):
        simulate_device_log("reactor", out, duration_s=-1)
