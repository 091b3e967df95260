"""The lab's own files, written by the libraries the lab's tools use (asammdf, rosbags in both storages, h5py), read
by identify / validate / record convert / replay; the resampling rule; bad input in one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lab_files as lab
from conftest import STREAMID, endpoint
from recorders import Recorder
from streamid.commands.main import main
from streamid.errors import DataError
from streamid.logs import read_log_arrays
from streamid.logs.datafile import load_record
from streamid.logs.timed import Signal, on_output_grid
from streamid.transport import ZenohSettings

N = 2000
U, Y = lab.plant(N)
ROS_IN, ROS_OUT = "/cmd_vel:linear.x", "/joint_states:velocity[2]"


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("lab")
    return {"mf4": lab.write_mf4(d / "bench.mf4"), "mcap": lab.write_bag(d / "bag_mcap", "mcap"),
            "sqlite3": lab.write_bag(d / "bag_db3", "sqlite3"), "mat73": lab.write_mat73(d / "bench73.mat"),
            "nodef": lab.write_bag(d / "bag_old", "sqlite3", definitions=False)}


def test_mf4_two_groups_and_a_conversion_on_the_output_grid(files: dict[str, Path]) -> None:
    rec = load_record(files["mf4"], ["throttle_V"], "speed_rpm")
    assert rec.period_ns == lab.OUT_PERIOD_NS and np.array_equal(rec.t_ns, np.arange(N) * lab.OUT_PERIOD_NS)
    np.testing.assert_allclose(rec.y, 1000 * Y)
    np.testing.assert_allclose(rec.u[:, 0], np.round(U * 1000) * 0.001)  # int16 counts x 0.001 V: converted
    assert any("faster than the output speed_rpm" in n and "1000 Hz" in n for n in rec.notes), rec.notes
    a = load_record(files["mf4"], ["temp_C@0"], "speed_rpm").u[:, 0]  # a name in two groups, by group
    b = load_record(files["mf4"], ["temp_C@1"], "speed_rpm").u[:, 0]
    np.testing.assert_allclose(a, 20 + np.sin(np.arange(N) * 0.01), atol=1e-9)
    np.testing.assert_allclose(b, 21 + np.cos(np.arange(N) * 0.01), atol=1e-9)


def test_an_mdf3_file_reads_as_its_mf4(files: dict[str, Path], tmp_path: Path) -> None:
    """``.mdf`` (MDF 3, CANape's and INCA's older format): the same channels, values and times as the MDF 4 file."""
    from asammdf import MDF

    mdf = MDF(str(files["mf4"]))
    mdf3 = mdf.convert("3.30")
    mdf3.save(str(tmp_path / "bench.mdf"), overwrite=True)
    mdf.close()
    mdf3.close()
    with open(tmp_path / "bench.mdf", "rb") as fh:
        assert fh.read(8) == b"MDF     " and b"3.30" in fh.read(16)
    a, b = load_record(tmp_path / "bench.mdf", ["throttle_V"], "speed_rpm"), load_record(files["mf4"], ["throttle_V"],
                                                                                         "speed_rpm")
    assert np.array_equal(a.t_ns, b.t_ns) and np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
    assert np.array_equal(load_record(tmp_path / "bench.mdf", ["temp_C@1"], "speed_rpm").u,
                          load_record(files["mf4"], ["temp_C@1"], "speed_rpm").u)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_bag_directory_and_its_file(files: dict[str, Path], storage: str) -> None:
    bag = files[storage]
    for path in (bag, next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))):
        rec = load_record(path, [ROS_IN], ROS_OUT)
        assert np.array_equal(rec.y, Y)  # the output keeps every sample, at its own time
        assert np.array_equal(rec.u[:, 0], U)  # the 20 Hz command held at each 100 Hz output time
        assert rec.t_ns is not None and int(rec.t_ns[0]) == 1_700_000_000_000_000_000 + 2_000_000
        assert rec.period_ns == lab.OUT_PERIOD_NS and rec.info["clock"] == ROS_OUT


def test_matlab_v73_by_h5py(files: dict[str, Path]) -> None:
    for u, y in (("u", "y"), ("X[0]", "X[1]"), ("s.u", "s.y")):
        rec = load_record(files["mat73"], [u], y)
        assert np.array_equal(rec.u[:, 0], U) and np.array_equal(rec.y, Y), (u, y)
    with pytest.raises(DataError, match=r"'label' is a MATLAB char value, not numbers"):
        load_record(files["mat73"], ["label"], "y")


def test_the_rule_holds_inputs_causally_cuts_and_refuses_with_rates() -> None:
    ms = 1_000_000
    out = Signal("y", np.arange(0, 200 * ms, 10 * ms, dtype=np.int64), np.arange(20.0))
    slow = Signal("u", np.array([30, 80, 130, 180], dtype=np.int64) * ms, np.array([1.0, 2.0, 3.0, 4.0]))
    t = on_output_grid("f", [slow], out, {})
    # from the first output time with an input sample (30 ms) to the last within one input period after its last
    assert list(t.t_ns // ms) == list(range(30, 200, 10))
    # held: a sample at an output time is that time's value, and nothing of a later sample is seen before it
    assert list(t.columns["u"]) == [1] * 5 + [2] * 5 + [3] * 5 + [4] * 2
    assert any("cut 3 of the output's 20 samples" in n for n in t.meta["notes"])  # type: ignore[attr-defined]
    late = Signal("u", np.arange(500, 600, 10, dtype=np.int64) * ms, np.ones(10))
    with pytest.raises(DataError, match=r"share 0 sample.*u spans 0.5-0.59 s at 100 Hz.*y spans 0-0.19 s at 100 Hz"):
        on_output_grid("f", [late], out, {})
    jitter = out.t_ns.copy()
    jitter[5:] += 20 * ms  # one dropout of the output in 20 samples: used (one place allowed), and said
    t = on_output_grid("f", [], Signal("y", jitter, out.values), {})
    assert len(t) == 20 and any("30 ms at 0.04 s" in n for n in t.meta["notes"])  # type: ignore[attr-defined]
    jitter[12:] += 20 * ms  # two: more than one place per 100 samples
    with pytest.raises(DataError, match=r"2 steps of the output y \(sampled at 100 Hz.*30 ms at 0.04 s"):
        on_output_grid("f", [], Signal("y", jitter, out.values), {})


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(argv)
    got = capsys.readouterr()
    return rc, got.out, got.err


def test_each_format_identifies_and_validates(files: dict[str, Path], tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    model = str(tmp_path / "m.json")
    fast = ["--generations", "4", "--restarts", "1", "--population", "10"]
    rc, out, err = _cli(["identify", str(files["sqlite3"]), "--input", ROS_IN, "--output", ROS_OUT, "--model", model,
                         *fast], capsys)
    assert rc == 0, err
    assert f"clock '{ROS_OUT}' (period 10 ms)" in out
    rc, out, err = _cli(["validate", model, str(files["mcap"]), "--input", ROS_IN, "--output", ROS_OUT, "--json",
                         "--min-r2-fr", "0.9"], capsys)
    assert rc == 0, err
    assert json.loads(out.splitlines()[-1])["passed"] is True
    for data, io in ((files["mf4"], ["--input", "throttle_V", "--output", "speed_rpm"]),
                     (files["mat73"], ["--input", "u", "--output", "y"])):
        rc, out, err = _cli(["identify", str(data), *io, *fast, "--json"], capsys)
        assert rc == 0, err
        assert json.loads(out.splitlines()[-1])["runs"][0]["r2"]["fr_val"] > 0.9, data


BAD = [
    ("mf4", ["--input", "nope", "--output", "speed_rpm"], r"no channel 'nope'.* it holds 4 channels: throttle_V, "
                                                          r"temp_C@\{0,1\}, speed_rpm, gear_state$"),
    ("mf4", ["--input", "temp_C", "--output", "speed_rpm"], r"'temp_C' is in 2 channel groups \(\[0, 1\]\).*temp_C@0"),
    ("mf4", ["--input", "throttle_V", "--output", "gear_state"], r"'gear_state' holds text values, not numbers"),
    ("mf4", [], r"(?=.*(give the channels to use|once per input\) --output SIGNAL|the columns default to the "
                r"model's signal names)).*it holds 4 channels: throttle_V"),
    ("sqlite3", [], r"it holds 3 topics: /cmd_vel \(geometry_msgs/msg/Twist\)"),
    ("mcap", ["--input", "/cmd:linear.x", "--output", ROS_OUT], r"no topic '/cmd'.*it holds 3 topics: /cmd_vel "
                                                                r"\(geometry_msgs/msg/Twist\), /joint_states"),
    ("mcap", ["--input", "/cmd_vel:linear.q", "--output", ROS_OUT], r"no field 'q'.*/cmd_vel:linear.x, "
                                                                    r"/cmd_vel:linear.y"),
    ("sqlite3", ["--input", ROS_IN, "--output", "/joint_states:name[0]"], r"is a str, not a number.*numeric fields "
                                                                          r"of /joint_states.*velocity\[2\]"),
    ("sqlite3", ["--input", ROS_IN, "--output", "/joint_states:velocity[7]"], r"has 3 elements; index 7 is out"),
    ("sqlite3", ["--input", "cmd_vel", "--output", ROS_OUT], r"a ROS 2 signal is /topic:field.path\[index\]"),
    ("nodef", ["--input", "/lab_cmd:level", "--output", ROS_OUT], r"type lab_msgs/msg/Command of /lab_cmd has no "
                                                                  r"definition in the bag nor among the standard"),
    ("mat73", ["--input", "label", "--output", "y"], r"'label' is a MATLAB char value"),
]


@pytest.fixture(scope="module")
def a_model(files: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-input model for ``streamid validate`` (identified from the sqlite3 bag, briefly)."""
    model = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["identify", str(files["sqlite3"]), "--input", ROS_IN, "--output", ROS_OUT, "--model", str(model),
                 "--generations", "2", "--restarts", "1", "--population", "6"]) == 0
    return model


def _every_command(data: Path, io: list[str], model: Path, out: Path) -> dict[str, list[str]]:
    """The four commands that read a data file, each on ``data`` with the signals ``io``."""
    return {"identify": ["identify", str(data), *io],
            "validate": ["validate", str(model), str(data), *io],
            "record convert": ["record", "convert", str(data), str(out), *io, "--period-ms", "10"],
            "replay": ["replay", str(data), *io, "--max-speed", "--connect", "tcp/127.0.0.1:9", "--wait-subscribers",
                       "0"]}


@pytest.mark.parametrize("kind,io,said", BAD, ids=[f"{k}-{i}" for i, (k, _, _) in enumerate(BAD)])
def test_bad_input_is_one_line_in_every_command(files: dict[str, Path], a_model: Path, tmp_path: Path, kind: str,
                                                io: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    for command, argv in _every_command(files[kind], io, a_model, tmp_path / "out.mcap").items():
        if command == "validate" and not io and kind != "mf4":
            continue  # (validate's signals default to the model's names, which are this bag's: nothing to refuse)
        rc, out, err = _cli(argv, capsys)
        assert rc == 2 and len(err.strip().splitlines()) == 1, (command, err)
        assert err.startswith(f"streamid {command.split()[0]}: error: "), (command, err)
        assert __import__("re").search(said, err.strip()), (command, err)
        assert not (tmp_path / "out.mcap").exists()  # nothing half-written


def test_the_old_bags_standard_types_still_decode(files: dict[str, Path]) -> None:
    rec = load_record(files["nodef"], [ROS_IN], ROS_OUT)  # Twist keeps its definition; lab_msgs has none
    assert np.array_equal(rec.y, Y)


def test_cut_and_damaged_files_one_line_no_traceback(files: dict[str, Path], a_model: Path, tmp_path: Path) -> None:
    """Cut, damaged or foreign files, through each of the four commands that read data, in a process of their own
    (a reader that fails while closing writes "Exception ignored ..." on stderr): one line each, exit 2."""
    import shutil

    cases = {}
    for kind, src in (("mf4", files["mf4"]), ("mcap", next(files["mcap"].glob("*.mcap"))),
                      ("db3", next(files["sqlite3"].glob("*.db3"))), ("mat", files["mat73"])):
        data = src.read_bytes()
        cut = tmp_path / f"cut.{kind}"
        cut.write_bytes(data[: len(data) // 2])
        cases[cut] = "a cut or damaged file is not read"
    head = tmp_path / "head.mf4"  # only its first 64 bytes: asammdf names its own buffer, not the file
    head.write_bytes(files["mf4"].read_bytes()[:64])
    cases[head] = "not a readable MDF file (MdfException: the file is not a valid MDF file)"
    junk = tmp_path / "junk.mf4"
    junk.write_bytes(b"garbage" * 50)
    cases[junk] = "not an ASAM MDF file"
    yaml = tmp_path / "bad_yaml_bag"  # a bag directory whose metadata.yaml does not parse: a YAML error of 5 lines
    shutil.copytree(files["mcap"], yaml)
    (yaml / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    cases[yaml] = "not a readable ROS 2 bag while opening it (AnyReaderError: Could not load YAML"
    flipped = tmp_path / "flipped_bag"  # bytes inverted inside its chunks: found while reading the messages
    shutil.copytree(files["mcap"], flipped)
    mcap = next(flipped.glob("*.mcap"))
    raw = bytearray(mcap.read_bytes())
    for i in np.random.default_rng(1).integers(len(raw) // 5, 4 * len(raw) // 5, 200):
        raw[i] ^= 0xFF
    mcap.write_bytes(bytes(raw))
    cases[flipped] = "not a readable ROS 2 bag while reading its messages"
    code = ("import sys\nfrom streamid.commands.main import main\nmodel, out, *paths = sys.argv[3:]\n"
            "for p in paths:\n"
            "    for argv in (['identify', p], ['validate', model, p], ['record', 'convert', p, out],\n"
            "                 ['replay', p, '--connect', 'tcp/127.0.0.1:9']):\n"
            "        print('rc', main(argv + ['--input', sys.argv[1], '--output', sys.argv[2]]), flush=True)\n")
    out = tmp_path / "out.mcap"
    p = subprocess.run([sys.executable, "-c", code, ROS_IN, ROS_OUT, str(a_model), str(out), *map(str, cases)],
                       capture_output=True, text=True, timeout=180)
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr
    assert p.stdout.split() == ["rc", "2"] * (4 * len(cases)), p.stdout
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 4 * len(cases), p.stderr
    for i, (path, said) in enumerate(cases.items()):
        for line, command in zip(lines[4 * i: 4 * i + 4], ("identify", "validate", "record", "replay")):
            assert line.startswith(f"streamid {command}: error: {path}: ") and said in line, line
    assert not out.exists()


def test_unknown_names_list_the_first_20_of_what_the_file_holds(tmp_path: Path) -> None:
    """A file of many channels, topics or variables: the line names how many, and shows the first 20."""
    import h5py
    from asammdf import MDF
    from asammdf import Signal as MdfSignal
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    t = np.arange(50) * 0.01
    mdf = MDF(version="4.10")
    mdf.append([MdfSignal(np.sin(t + k), t, name=f"ch{k:02d}") for k in range(25)])
    mdf.save(str(tmp_path / "many.mf4"), overwrite=True)
    mdf.close()
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(tmp_path / "many_bag", version=9) as w:
        for k in range(25):
            c = w.add_connection(f"/t{k:02d}", "std_msgs/msg/Float64", typestore=ts)
            w.write(c, 1_000 + k, ts.serialize_cdr(ts.types["std_msgs/msg/Float64"](float(k)), "std_msgs/msg/Float64"))
    with h5py.File(tmp_path / "many73.mat", "w", userblock_size=512) as f:
        for k in range(25):
            f.create_dataset(f"v{k:02d}", data=t[None, :]).attrs["MATLAB_class"] = np.bytes_("double")
    lab.matlab_header(tmp_path / "many73.mat")
    for path, signal, said in (
            ("many.mf4", "nope", r"it holds 25 channels \(the first 20 shown\): ch00, ch01, .*, ch19$"),
            ("many_bag", "/nope:data", r"it holds 25 topics \(the first 20 shown\): /t00 \(std_msgs/msg/Float64\), "
                                       r".*, /t19 \(std_msgs/msg/Float64\)$"),
            ("many73.mat", "nope", r"available columns: \['v00', 'v01', .*, 'v19'\] and 5 more$")):
        with pytest.raises(DataError) as err:
            load_record(tmp_path / path, [signal], signal if path != "many_bag" else "/t00:data")
        text = str(err.value)
        assert __import__("re").search(said, text) and "\n" not in text, text
        assert not any(f"{k}20" in text for k in ("ch", "/t", "v")), text  # the 21st name is not listed


def test_a_missing_reader_names_the_extra(files: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    for module, path in (("asammdf", files["mf4"]), ("rosbags", files["mcap"]), ("h5py", files["mat73"])):
        with monkeypatch.context() as m:
            m.setitem(sys.modules, module, None)  # import fails as if not installed
            with pytest.raises(DataError, match=rf"needs the Python library '{module}'.*streamid's extra 'lab' \(pip "
                               rf"install '\.\[lab\]'.*pip install 'streamid\[lab\]'.*pip install {module}$"):
                load_record(path, ["a"], "b")
    with monkeypatch.context() as m:  # a daemon's [streams.X.ros2] stream without rosbags: the same line
        m.setitem(sys.modules, "rosbags", None)
        from streamid.daemon.ros2_config import Ros2Source
        from streamid.daemon.ros2_intake import Ros2Intake

        with pytest.raises(DataError, match=r"ROS 2 bags and CDR messages needs the Python library 'rosbags'.*'lab'"):
            Ros2Intake("s", Ros2Source(inputs=(ROS_IN,), output=ROS_OUT), lambda b: None, lambda k, m: None)


def test_record_convert_then_replay_a_bag_and_an_mf4(files: dict[str, Path], tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "robot.mcap"
    rc, out, err = _cli(["record", "convert", str(files["mcap"]), str(log), "--input", ROS_IN, "--output", ROS_OUT,
                         "--stream", "robot"], capsys)
    assert rc == 0, err
    assert f"{N} samples of {ROS_IN} -> {ROS_OUT} (period 10 ms) as stream 'robot'" in out
    arr = read_log_arrays(log)
    assert arr.stream == "robot" and np.array_equal(arr.outputs[ROS_OUT], Y) and np.array_equal(arr.inputs[ROS_IN], U)
    assert int(arr.t_ns[0]) == 1_700_000_000_000_000_000 + 2_000_000
    rc, out, err = _cli(["record", "convert", str(files["mat73"]), str(tmp_path / "m.mcap"), "--input", "u",
                         "--output", "y"], capsys)
    assert rc == 2 and "give the sample period (--period-ms MS)" in err
    ep = endpoint()
    rec_path = tmp_path / "played.mcap"
    with Recorder(rec_path, ZenohSettings(listen=(ep,))) as rec:
        play = subprocess.run([*STREAMID, "replay", str(files["mf4"]), "--input", "throttle_V", "--output",
                               "speed_rpm", "--stream", "bench", "--max-speed", "--connect", ep,
                               "--wait-subscribers", "20", "--json"], capture_output=True, text=True, timeout=120)
        assert play.returncode == 0, play.stderr
        report = json.loads(play.stdout.splitlines()[-1])
        assert report["samples"] == N and report["per_key"] == {"streamid/bench/samples": N // 100}
        assert rec.wait_for(report["messages"], 20.0)
    got = read_log_arrays(rec_path)
    np.testing.assert_allclose(got.outputs["speed_rpm"], 1000 * Y)
    assert "streamid replay: " in play.stderr and "as stream 'bench'" in play.stderr


def test_cdr_payloads_serialised_by_rosbags_decode_and_garbage_is_one_error() -> None:
    from rosbags.typesys import Stores, get_typestore

    from streamid.logs.ros2_bag import CdrDecoder
    from streamid.logs.ros2_fields import parse_signal

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    raw = ts.serialize_cdr(T["geometry_msgs/msg/Twist"](T["geometry_msgs/msg/Vector3"](0.25, 0.0, 0.0),
                                                        T["geometry_msgs/msg/Vector3"](0.0, 0.0, -1.5)),
                           "geometry_msgs/msg/Twist")
    dec = CdrDecoder({"lab_msgs/msg/Command": "float64 level"})
    assert dec.knows("geometry_msgs/msg/Twist") and dec.knows("lab_msgs/msg/Command") and not dec.knows("x/msg/Y")
    msg = dec.decode(bytes(raw), "geometry_msgs/msg/Twist")
    assert parse_signal("/cmd_vel:linear.x").value(msg) == 0.25
    assert parse_signal("/cmd_vel:angular.z").value(msg) == -1.5
    with pytest.raises(DataError, match=r"a payload of 3 bytes is not geometry_msgs/msg/Twist in CDR"):
        dec.decode(b"\x00\x01\x00", "geometry_msgs/msg/Twist")
    with pytest.raises(DataError, match=r"the message definition of bad/msg/X does not parse"):
        CdrDecoder({"bad/msg/X": "float64 [[[ nonsense"})
