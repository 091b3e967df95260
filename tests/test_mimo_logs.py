"""The bundled MIMO logs (F-16 GVT: 1 -> 3, CSTR: 1 -> 2) equal their sources and replay onto Zenoh whole."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA_DIR, STREAMID, endpoint, rerun_check
from recorders.convert import REAL_LOGS, convert, main as convert_main
from streamid import logs as mcaplog
from streamid.errors import DataError
from streamid.transport import Bus, ZenohSettings
from streamid.wire import codec

F16_OUT = ["accel1_au", "accel2_au", "accel3_au"]
CSTR_OUT = ["concentration_mol_l", "temperature_K"]


def _csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and rows, every field parsed by Python's own float (the nearest float64)."""
    lines = path.read_text(encoding="ascii").splitlines()
    rows = [[float(f) for f in line.split(",")] for line in lines[1:] if line.strip()]
    return lines[0].split(","), np.array(rows, dtype=np.float64)


def test_f16_log_equals_the_two_benchmark_periods_exactly() -> None:
    h_est, est = _csv(DATA_DIR / "f16_gvt" / "f16_est.csv")
    h_val, val = _csv(DATA_DIR / "f16_gvt" / "f16_val.csv")
    assert h_est == h_val == ["Force", "Acceleration1", "Acceleration2", "Acceleration3"]
    assert est.shape == val.shape == (8192, 4)
    src = np.concatenate([est, val])
    a = mcaplog.read_log_arrays(mcaplog.bundled_log("f16_gvt"))
    assert a.stream == "f16_gvt" and len(a) == 16_384 and a.period_ns == 2_500_000  # 400 Hz
    assert list(a.inputs) == ["force_N"] and list(a.outputs) == F16_OUT
    assert a.u().shape == (16_384, 1) and a.y().shape == (16_384, 3)
    assert a.u()[:, 0].tobytes() == src[:, 0].tobytes()
    assert a.y().tobytes() == np.ascontiguousarray(src[:, 1:]).tobytes()
    assert a.t_ns.tolist() == (2_500_000 * np.arange(16_384)).tolist()
    meta = a.metadata["streamid"]
    assert meta["estimation_samples"].startswith("8192") and "0bdf70605da2570cca526659b3b21e6356e7bb48" in (
        meta["source_repository"])
    assert "no licence file" in meta["licence"] and "Noel & Schoukens" in meta["licence"]
    # no batch straddles the junction: `replay f16_gvt --start 20.48` plays exactly the validation part
    first = [codec.decode(d) for _, t, d in mcaplog.iter_log(mcaplog.bundled_log("f16_gvt")) if t < 20_480_000_000]
    assert sum(len(b) for b in first) == 8192 and first[-1].t0_ns + 31 * 2_500_000 == 20_477_500_000
    # the benchmark's levels: 36.8 N RMS (estimation), 24.6 N RMS (validation)
    assert float(np.sqrt(np.mean(a.u()[:8192, 0] ** 2))) == pytest.approx(36.85, abs=0.01)
    assert float(np.sqrt(np.mean(a.u()[8192:, 0] ** 2))) == pytest.approx(24.64, abs=0.01)


def test_cstr_log_equals_the_daisy_record_exactly() -> None:
    header, src = _csv(DATA_DIR / "cstr" / "cstr.csv")
    assert header == ["t_min", "q", "Ca", "T"] and src.shape == (7500, 4)
    a = mcaplog.read_log_arrays(mcaplog.bundled_log("cstr"))
    assert a.stream == "cstr" and len(a) == 7500 and a.period_ns == 6_000_000_000  # Ts = 0.1 min
    assert list(a.inputs) == ["coolant_flow_l_min"] and list(a.outputs) == CSTR_OUT
    assert a.u().shape == (7500, 1) and a.y().shape == (7500, 2)
    assert a.inputs["coolant_flow_l_min"].tobytes() == src[:, 1].tobytes()
    assert a.outputs["concentration_mol_l"].tobytes() == src[:, 2].tobytes()
    assert a.outputs["temperature_K"].tobytes() == src[:, 3].tobytes()
    # sample times are the source's t_min in ns: 0.1 min = 6 s, from 6 s
    assert a.t_ns.tolist() == (6_000_000_000 * np.arange(1, 7501)).tolist()
    assert np.array_equal(np.round(src[:, 0] * 60e9).astype(np.int64), a.t_ns)
    meta = a.metadata["streamid"]
    assert meta["source"].startswith("SIMULATED") and "MIT" in meta["licence"]


@pytest.mark.parametrize(("name", "source"), [("f16_gvt", "f16_gvt"), ("cstr", "cstr/cstr.csv")])
def test_mimo_conversion_is_reproducible(name: str, source: str, tmp_path: Path) -> None:
    out = tmp_path / f"{name}.mcap"
    assert convert_main([name, str(DATA_DIR / source), str(out)]) == 0
    fresh = [tuple(m) for m in mcaplog.iter_log(out)]
    assert fresh == [tuple(m) for m in mcaplog.iter_log(mcaplog.bundled_log(name))] and len(fresh) > 400
    assert REAL_LOGS[name].source_file == source


def test_mimo_logs_are_packaged_with_their_provenance() -> None:
    assert {"f16_gvt", "cstr"} <= set(mcaplog.bundled_logs())
    data = resources.files("streamid") / "data"
    f16 = (data / "f16_gvt.PROVENANCE.md").read_text(encoding="utf-8")
    cstr = (data / "cstr.PROVENANCE.md").read_text(encoding="utf-8")
    assert "0bdf70605da2570cca526659b3b21e6356e7bb48" in f16 and "Licence: not settled" in f16
    assert "rows 65537–73728" in f16 and "Noël and M. Schoukens" in f16
    assert "MIT License" in cstr and "Marco Forgione" in cstr and "SIMULATED" in cstr
    for name in ("f16_gvt", "cstr"):
        assert (DATA_DIR / name / "PROVENANCE.md").read_text(encoding="utf-8") == (
            data / f"{name}.PROVENANCE.md").read_text(encoding="utf-8")
        assert mcaplog.bundled_log(name).stat().st_size < 400_000  # small: a few hundred KB at most
        res = rerun_check(mcaplog.bundled_log(name))
        assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.parametrize(("name", "n_samples", "n_messages"), [("f16_gvt", 16_384, 512), ("cstr", 7500, 750)])
def test_replay_max_speed_delivers_every_sample_to_a_zenoh_subscriber(
    name: str, n_samples: int, n_messages: int
) -> None:
    ep = endpoint()
    got: list[codec.SampleBatch] = []
    lock = threading.Lock()

    def on_sample(key: str, payload: bytes) -> None:
        batch = codec.decode(payload)
        with lock:
            got.append(batch)

    with Bus(ZenohSettings(listen=(ep,))) as bus:
        bus.subscribe(f"streamid/{name}/**", on_sample)
        play = subprocess.run(
            STREAMID + ["replay", name, "--connect", ep, "--max-speed", "--wait-subscribers", "20", "--json"],
            capture_output=True, text=True, timeout=120,
        )
        assert play.returncode == 0, play.stderr
        report = json.loads(play.stdout.strip().splitlines()[-1])
        assert report["messages"] == n_messages and report["samples"] == n_samples
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            with lock:
                if len(got) >= n_messages:
                    break
            time.sleep(0.05)
    with lock:
        batches = sorted(got, key=lambda b: b.seq)
    assert [b.seq for b in batches] == list(range(n_messages))  # all, once each
    original = mcaplog.read_log_arrays(mcaplog.bundled_log(name))
    t = np.concatenate([b.times_ns() for b in batches])
    assert t.tolist() == original.t_ns.tolist()
    for role, chans in (("inputs", original.inputs), ("outputs", original.outputs)):
        for ch, values in chans.items():
            sent = np.concatenate([getattr(b, role)[ch] for b in batches])
            assert sent.tobytes() == values.tobytes(), (role, ch)


def test_convert_names_the_offending_value(tmp_path: Path) -> None:
    folder = tmp_path / "f16"
    folder.mkdir()
    (folder / "f16_est.csv").write_text("Force,Acc1,Acceleration2,Acceleration3\n1,2,3,4\n")
    with pytest.raises(DataError, match=r"header row must be 'Force,Acceleration1,.*got 'Force,Acc1"):
        convert("f16_gvt", folder, tmp_path / "o.mcap")
    (folder / "f16_est.csv").write_text("Force,Acceleration1,Acceleration2,Acceleration3\n1,2,3,4\n")
    with pytest.raises(DataError, match="one multisine period, 8192 rows; got 1"):
        convert("f16_gvt", folder, tmp_path / "o.mcap")
    bad = tmp_path / "cstr.csv"
    bad.write_text("t_min,q,Ca,T\n0.1,100,0.1,440\n0.2,1e,0.1,440\n")
    with pytest.raises(DataError, match=r"line 3 must hold 4 comma-separated numbers; got '0.2,1e,0.1,440'"):
        convert("cstr", bad, tmp_path / "o.mcap")
    bad.write_text("t_min,q,Ca,T\n0.1,100,0.1,440\n0.3,100,0.1,440\n")
    with pytest.raises(DataError, match="line 3 has 0.3, expected 0.2"):
        convert("cstr", bad, tmp_path / "o.mcap")
    bad.write_text("t_min,q,Ca,T\n0.1,nan,0.1,440\n")
    with pytest.raises(DataError, match="line 2, column 'q' must be finite; got nan"):
        convert("cstr", bad, tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()
