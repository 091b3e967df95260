"""Live ROS 2 topics as a daemon stream (``[streams.X.ros2]``), over real Zenoh sessions on loopback.

The messages are real ROS 2 CDR, serialised by ``rosbags`` (the typestore's ``serialize_cdr``), published on exactly
the keys rmw_zenoh (with its attachment: sequence number, source timestamp, GID) and zenoh-bridge-ros2dds use.  A
first-order system is driven at two rates (input 200 Hz, output 100 Hz); the daemon must grid them by the file
readers' rule (checked sample for sample against :func:`streamid.logs.timed.on_output_grid`), identify the system
(a published model, free-run R² near 1) and count a corrupt payload per topic without stopping the stream.
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import STREAMID, endpoint

pytest.importorskip("rosbags")

from streamid.daemon.config import DaemonConfig, StreamConfig, config_from_mapping, load_config, to_toml  # noqa: E402
from streamid.daemon.ros2_config import Ros2Source  # noqa: E402
from streamid.daemon.ros2_intake import Ros2Intake  # noqa: E402
from streamid.errors import ConfigError  # noqa: E402
from streamid.logs.ros2_bag import standard_types  # noqa: E402
from streamid.logs.timed import Signal, on_output_grid  # noqa: E402
from streamid.wire.codec import SampleBatch  # noqa: E402

DOC = Path(__file__).resolve().parents[1] / "docs" / "daemon.md"
T0 = 1_700_000_000_000_000_000
HASH = "RIHS01_" + "5e" * 32
U_KEY = f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/{HASH}"
Y_KEY = f"0/joint_states/sensor_msgs::msg::dds_::JointState_/{HASH}"
STORE = standard_types()
TY = STORE.types
FAST = dict(cold_generations=20, warm_generations=5, neurons=4, max_lag_y=2, max_lag_u=2, population=12,
            challenger_margin=-1.0, seed=1)


def doc_example() -> dict[str, Any]:
    """The first TOML block of docs/daemon.md's "ROS 2 topics" section, parsed as written."""
    text = DOC.read_text(encoding="utf-8").split("## ROS 2 topics", 1)[1]
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block is not None
    return tomllib.loads(block.group(1))


def _stamp(t_ns: int) -> Any:
    return TY["std_msgs/msg/Header"](stamp=TY["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                     frame_id="")


def twist(x: float) -> bytes:
    v3 = TY["geometry_msgs/msg/Vector3"]
    msg = TY["geometry_msgs/msg/Twist"](linear=v3(x=x, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0))
    return bytes(STORE.serialize_cdr(msg, "geometry_msgs/msg/Twist"))


def twist_stamped(t_ns: int, x: float) -> bytes:
    v3 = TY["geometry_msgs/msg/Vector3"]
    tw = TY["geometry_msgs/msg/Twist"](linear=v3(x=x, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0))
    msg = TY["geometry_msgs/msg/TwistStamped"](header=_stamp(t_ns), twist=tw)
    return bytes(STORE.serialize_cdr(msg, "geometry_msgs/msg/TwistStamped"))


def joint_states(t_ns: int, velocity: list[float]) -> bytes:
    n = len(velocity)
    msg = TY["sensor_msgs/msg/JointState"](header=_stamp(t_ns), name=[f"j{i}" for i in range(n)],
                                           position=np.zeros(n), velocity=np.array(velocity), effort=np.zeros(n))
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def attachment(seq: int, t_ns: int) -> bytes:
    """rmw_zenoh's attachment: int64 sequence number, int64 source timestamp (LE), GID length, 16-byte GID."""
    return seq.to_bytes(8, "little") + t_ns.to_bytes(8, "little") + bytes([16]) + bytes(range(16))


def first_order(n_out: int, seed: int) -> tuple[list[tuple[int, float]], list[tuple[int, float]]]:
    """(input samples at 200 Hz, output samples at 100 Hz): y[k+1] = 0.9 y[k] + 0.5 u(t_k), u held, random steps."""
    rng = np.random.default_rng(seed)
    u_samples, y_samples = [], []
    level, y = 0.0, 0.0
    for k in range(n_out):
        held = level
        for j in range(2):
            if (2 * k + j) % 14 == 0:
                level = float(rng.uniform(-1.0, 1.0))
            u_samples.append((T0 + k * 10_000_000 + j * 5_000_000 + 1_000_000, level))
            if j == 0:
                held = level
        y_samples.append((T0 + k * 10_000_000 + 2_000_000, y))
        y = 0.9 * y + 0.5 * held
    return u_samples, y_samples


# ------------------------------------------------------------------------------------------- configuration
def test_the_documented_example_loads_as_written(tmp_path: Path) -> None:
    cfg = config_from_mapping(doc_example(), "docs/daemon.md")
    src = cfg.ros2_of("arm")
    assert src == Ros2Source(inputs=("/cmd_vel:linear.x",), output="/joint_states:velocity[2]", layout="rmw_zenoh",
                             types=(("/cmd_vel", "geometry_msgs/msg/Twist"),
                                    ("/joint_states", "sensor_msgs/msg/JointState")))
    assert cfg.streams == ("arm",) and not cfg.discover  # served from the start, as if listed
    assert [src.key_expr(t) for t in src.topics()] == ["0/cmd_vel/geometry_msgs::msg::dds_::Twist_/*",
                                                      "0/joint_states/sensor_msgs::msg::dds_::JointState_/*"]
    assert src.topic_of(U_KEY) == ("/cmd_vel", "geometry_msgs/msg/Twist")
    (tmp_path / "back.toml").write_text(to_toml(cfg))
    back = load_config(tmp_path / "back.toml")  # --print-config's TOML reads back to the same ROS 2 source
    assert back.ros2 == cfg.ros2 and back.streams == cfg.streams and to_toml(back) == to_toml(cfg)


@pytest.mark.parametrize(("table", "said"), [
    ({"inputs": ["/u:data"], "output": "/y:data", "layout": "bridge"}, "bridge layout's keys do not say"),
    ({"inputs": ["/u:data"], "output": "/y:data", "layout": "dds"}, "ros2.layout must be one of rmw_zenoh, bridge"),
    ({"inputs": ["/u:data"], "output": "/y:data", "rate": 5}, "unknown key streams.s.ros2.'rate'"),
    ({"inputs": ["/u:data"], "output": "y data"}, "a ROS 2 signal is /topic:field.path[index]"),
    ({"inputs": ["/u:data"], "output": "/y:data", "max_pending": 1}, "ros2.max_pending must be an integer"),
    ({"inputs": ["/u:data"], "output": "/y:data", "types": {"/u": "Float64"}}, "a ROS 2 message type is pkg/msg/Name"),
])
def test_a_bad_table_is_refused_in_one_line_naming_it(table: dict[str, Any], said: str) -> None:
    with pytest.raises(ConfigError) as err:
        config_from_mapping({"streams": {"s": {"ros2": table}}}, "d.toml")
    text = str(err.value)
    assert said in text and "\n" not in text and text.startswith("d.toml: ")


@pytest.mark.parametrize(("prelude", "said"), [
    ("", "[streams.arm.ros2.types]: /u's type lab_msgs/msg/Nope is not among the standard ROS 2 messages"),
    ("sys.modules['rosbags'] = None; ", "needs the Python library 'rosbags', which is not installed: it comes with "
                                        "streamid's extra 'lab' (pip install '.[lab]'"),
])
def test_streamid_daemon_refuses_what_it_cannot_decode_in_one_line(tmp_path: Path, prelude: str, said: str) -> None:
    """At start, before any message: a configured type without a definition, and rosbags not installed."""
    cfg = tmp_path / "d.toml"
    cfg.write_text('[streams.arm.ros2]\ninputs = ["/u:data"]\noutput = "/y:data"\n[streams.arm.ros2.types]\n'
                   '"/u" = "lab_msgs/msg/Nope"\n"/y" = "std_msgs/msg/Float64"\n' if not prelude else
                   '[streams.arm.ros2]\ninputs = ["/u:data"]\noutput = "/y:data"\n')
    code = (f"import sys; {prelude}from streamid.commands.main import main; sys.exit(main(['daemon', '--config', "
            f"{str(cfg)!r}, '--listen', 'tcp/127.0.0.1:0', '--no-rerun', '--duration', '5']))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    (line,) = p.stderr.strip().splitlines()
    assert line.startswith("streamid daemon: error: ") and said in line, line


# ---------------------------------------------------------------------------------- the grid, without Zenoh
def _intake(source: Ros2Source) -> tuple[Ros2Intake, list[SampleBatch], list[tuple[str, str]]]:
    batches: list[SampleBatch] = []
    bad: list[tuple[str, str]] = []
    return Ros2Intake("s", source, batches.append, lambda k, m: bad.append((k, m))), batches, bad


def test_live_grid_is_the_file_rule_sample_for_sample() -> None:
    src = Ros2Source(inputs=("/cmd_vel:linear.x",), output="/joint_states:velocity[2]")
    intake, batches, bad = _intake(src)
    u, y = first_order(120, seed=3)
    early = [(T0 - 30_000_000 + i * 10_000_000, 0.0) for i in range(3)]  # output samples before any input: cut
    y = early + y
    msgs = [(t, "u", v) for t, v in u] + [(t, "y", v) for t, v in y]
    msgs.sort(key=lambda m: (m[0] + (4_000_000 if m[1] == "u" else 0)))  # inputs arrive late (another path)
    for i, (t, kind, v) in enumerate(msgs):
        if kind == "u":
            intake.on_message(U_KEY, twist(v), None, attachment(i, t), now_ns=0)
        else:
            intake.on_message(Y_KEY, joint_states(t, [0.0, 0.0, v]), None, None, now_ns=0)
    assert not bad
    live_t = np.concatenate([b.times_ns() for b in batches])
    live_u = np.concatenate([b.inputs["/cmd_vel:linear.x"] for b in batches])
    live_y = np.concatenate([b.outputs["/joint_states:velocity[2]"] for b in batches])
    sig = [Signal(n, np.array([t for t, _ in s], dtype=np.int64), np.array([v for _, v in s]))
           for n, s in (("/cmd_vel:linear.x", u), ("/joint_states:velocity[2]", y))]
    table = on_output_grid("file", sig[:1], sig[1], {})
    n = live_t.size
    assert n >= 115 and np.array_equal(live_t, table.t_ns[:n])
    assert np.array_equal(live_u, table.columns["/cmd_vel:linear.x"][:n])
    assert np.array_equal(live_y, table.columns["/joint_states:velocity[2]"][:n])
    status = intake.status()
    assert status["cut_before_inputs"] == 3 and status["samples_taken"] == n
    assert status["topics"]["/cmd_vel"]["clock"] == "rmw_zenoh source timestamp"
    assert status["topics"]["/joint_states"]["clock"] == "header.stamp"


def test_a_first_batch_of_one_kept_output_waits_for_the_next_and_loses_none() -> None:
    # what CI met with arrival times: y(0) before u(0) (cut), then u(0), y(1), u(1): the first grid holds y(0) (cut)
    # and y(1) (kept, alone: a stream's first batch needs two) -- y(1) was popped and counted nowhere
    src = Ros2Source(inputs=("/cmd_vel:linear.x",), output="/joint_states:velocity[2]")
    intake, batches, bad = _intake(src)
    step = 10_000_000
    order = [("y", 0), ("u", 0), ("y", 1), ("u", 1)] + [(k, i) for i in range(2, 12) for k in ("u", "y")]
    for j, (kind, i) in enumerate(order):
        t = T0 + i * step + (1_000_000 if kind == "y" else 0)  # y(i) a millisecond after u(i) on the clock...
        if kind == "y" and i == 0:
            t = T0 - 1_000_000  # ...but y(0) before every input
        if kind == "u":
            intake.on_message(U_KEY, twist(float(i)), None, attachment(j, t), now_ns=0)
        else:
            intake.on_message(Y_KEY, joint_states(t, [0.0, 0.0, float(i)]), None, None, now_ns=0)
    assert not bad
    status = intake.status()
    taken = np.concatenate([b.outputs["/joint_states:velocity[2]"] for b in batches])
    # y(1)..y(10); y(11) waits for an input after it (the old code took y(2)..y(10): 9)
    assert status["cut_before_inputs"] == 1 and status["samples_taken"] == taken.size == 10
    assert taken.tolist() == [float(i) for i in range(1, 11)]


def test_bad_messages_are_counted_per_topic_and_every_queue_is_bounded() -> None:
    src = Ros2Source(inputs=("/cmd_vel:linear.x",), output="/joint_states:velocity[2]", max_pending=50,
                     max_keys_per_topic=2)
    intake, batches, bad = _intake(src)
    intake.on_message(Y_KEY, b"\x00\x01\x00\x00\xff", None, None, now_ns=1)  # does not decode
    intake.on_message(Y_KEY, joint_states(T0, [1.0, 2.0]), None, None, now_ns=1)  # velocity[2] out of range
    intake.on_message("0/joint_states/not_a_type/x", joint_states(T0, [1.0, 2.0, 3.0]), None, None, now_ns=1)
    intake.on_message("0/cmd_vel/std_msgs::msg::dds_::Float64_/h", b"\x00\x01\x00\x00" + bytes(8), None, None, 1)
    for i in range(3):  # the third and fourth keys on /cmd_vel: beyond max_keys_per_topic
        intake.on_message(f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/h{i}", twist(0.0), None, None, now_ns=1)
    for i in range(80):  # an output whose input never passes it: its queue stays at max_pending
        intake.on_message(Y_KEY, joint_states(T0 + i * 10_000_000, [0.0, 0.0, 1.0]), None, None, now_ns=1)
    intake.on_message(Y_KEY, joint_states(T0, [0.0, 0.0, 1.0]), None, None, now_ns=1)  # not after the last
    intake.too_large(Y_KEY, 10**7)
    st = intake.status()
    y_bad, u_bad = st["topics"]["/joint_states"]["bad"], st["topics"]["/cmd_vel"]["bad"]
    assert y_bad == {"decode": 1, "field": 1, "type": 1, "time": 1, "too_large": 1}
    assert u_bad == {"field": 1, "too_many_keys": 2}  # Float64 has no linear.x; the third and fourth keys
    assert st["topics"]["/joint_states"]["pending"] == 50
    assert st["topics"]["/joint_states"]["pending_dropped"] == 30
    assert st["bad_total"] == 8 and len(bad) == 8 and all(k.startswith("ros2_") for k, _ in bad)
    assert "index 2 is out of range" in " ".join(m for _, m in bad)


# ------------------------------------------------------------------------------------- the daemon, live
@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from streamid.daemon.service import Daemon
    from streamid.transport import Bus, ZenohSettings
    from streamid.transport.client import latest_model, latest_status
    from streamid.viz.rerun_view import Viz, VizSettings

    data = doc_example()
    data["streams"]["arm"].update(FAST)
    data["streams"]["rig"] = {"window_s": 2.0, "update_every_s": 1.0, **FAST,
                              "ros2": {"layout": "bridge", "key_prefix": "lab", "inputs": ["/cmd:twist.linear.x"],
                                       "output": "/joints:velocity[0]",
                                       "types": {"/cmd": "geometry_msgs/msg/TwistStamped",
                                                 "/joints": "sensor_msgs/msg/JointState"}}}
    # every message is published as fast as the bus carries it (stream time from the stamps): above the fair
    # intake budget's default 5000 messages/s while both streams send (tested in tests/test_fair_intake.py)
    data["daemon"] = {"workers": 1, "helper": False, "status_every_s": 0.2, "max_batches_per_s": 10**7}
    cfg: DaemonConfig = config_from_mapping(data)
    assert isinstance(cfg.for_stream("arm"), StreamConfig)
    ep = endpoint()
    rrd = tmp_path_factory.mktemp("ros2_rrd") / "diag.rrd"
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,)), viz=Viz(VizSettings(rrd=str(rrd)))).start()
    out: dict[str, Any] = {"n_out": 600, "rrd": rrd}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as bus:
            assert bus.wait_connected(10)
            time.sleep(0.3)  # the daemon's subscriptions reach this session
            for name, seed in (("arm", 11), ("rig", 12)):
                u, y = first_order(out["n_out"], seed)
                for k, (ty, vy) in enumerate(y):
                    for j in (0, 1):
                        tu, vu = u[2 * k + j]
                        if name == "arm":
                            bus.put(U_KEY, twist(vu), attachment=attachment(2 * k + j, tu))
                        else:
                            bus.put("lab/cmd", twist_stamped(tu, vu))
                    key = Y_KEY if name == "arm" else "lab/joints"
                    bus.put(key, joint_states(ty, [0.0, 0.0, vy] if name == "arm" else [vy]))
                    if k == 300:  # a corrupt payload mid-stream: counted, the stream goes on
                        bus.put(key, b"\x00\x01\x00\x00corrupt")
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                docs = {s: latest_status(bus, s, timeout_s=1.0) for s in ("arm", "rig")}
                if all(d and d["version"] >= 2 and not d["busy"] and not d["windows"]["pending"]
                       and d["ros2"]["samples_taken"] >= out["n_out"] - 1 for d in docs.values()):
                    break
                time.sleep(0.2)
            out["status"] = docs
            out["models"] = {s: latest_model(bus, s, timeout_s=2.0, default=None) for s in ("arm", "rig")}
        out["table"] = subprocess.run([*STREAMID, "status", "--connect", ep, "--timeout", "3"], capture_output=True,
                                      text=True, timeout=60)
    finally:
        daemon.stop()
    return out


@pytest.mark.parametrize("stream", ["arm", "rig"])
def test_a_ros2_stream_gets_a_model_of_the_system(live: dict[str, Any], stream: str) -> None:
    model = live["models"][stream]
    assert model is not None, live["status"][stream]
    assert list(model.model.input_names) == (["/cmd_vel:linear.x"] if stream == "arm" else ["/cmd:twist.linear.x"])
    assert model.metrics["r2_fr_val"] > 0.9  # y[k+1] = 0.9 y[k] + 0.5 u: a first-order system, exactly
    st = live["status"][stream]
    assert st["ros2"]["layout"] == ("rmw_zenoh" if stream == "arm" else "bridge")


@pytest.mark.parametrize("stream", ["arm", "rig"])
def test_a_corrupt_payload_is_counted_and_the_stream_goes_on(live: dict[str, Any], stream: str) -> None:
    st = live["status"][stream]
    out_topic = "/joint_states" if stream == "arm" else "/joints"
    topic = st["ros2"]["topics"][out_topic]
    assert topic["bad"] == {"decode": 1} and topic["received"] == live["n_out"] + 1
    assert st["bad"].get("ros2_decode") == 1
    assert st["ros2"]["samples_taken"] >= live["n_out"] - 1  # every output sample after it was taken too
    in_topic = st["ros2"]["topics"]["/cmd_vel" if stream == "arm" else "/cmd"]
    assert in_topic["clock"] == ("rmw_zenoh source timestamp" if stream == "arm" else "header.stamp")
    assert in_topic["period_ns"] == 5_000_000 and topic["period_ns"] == 10_000_000  # each topic at its own rate


@pytest.mark.parametrize("stream", ["arm", "rig"])
def test_a_ros2_streams_rerun_diagnostics_are_any_streams(live: dict[str, Any], stream: str) -> None:
    """The .rrd the daemon wrote, read back with rerun's reader: the stream's tab holds the views every stream gets,
    the measured output there being the ROS 2 field's values."""
    from rerun.chunk import RrdReader

    base = f"/streams/{stream}"
    chunks = RrdReader(live["rrd"]).stream().filter(content=f"{base}/**").to_chunks()
    paths = {c.entity_path for c in chunks}
    for view in ("validation/measured", "residual/osa", "residual/free_run", "fitness", "correlation/ee/value",
                 "history/r2_fr", "model"):
        assert f"{base}/{view}" in paths, (view, sorted(paths))
    measured = [c for c in chunks if c.entity_path == f"{base}/validation/measured"]
    batches = [c.to_record_batch() for c in measured]
    shown = [v for b in batches if "Scalars:scalars" in b.schema.names
             for row in b.column("Scalars:scalars").to_pylist() for v in row]
    sent = {v for _, v in first_order(live["n_out"], 11 if stream == "arm" else 12)[1]}
    assert len(shown) >= 100 and set(shown) <= sent  # the validation part of a window: the published field's values


def test_streamid_status_shows_each_topics_counters(live: dict[str, Any]) -> None:
    table = live["table"]
    assert table.returncode == 0, table.stderr
    lines = [ln for ln in table.stdout.splitlines() if "ros2 /joint_states" in ln]
    assert len(lines) == 1 and "1 bad (decode 1)" in lines[0] and "clock header.stamp" in lines[0]


def test_the_example_runs_unchanged_but_for_the_engine() -> None:
    """The documented stream's settings reach the daemon as written (window, update period, the ROS 2 source)."""
    cfg = config_from_mapping(doc_example())
    sc = cfg.for_stream("arm")
    assert (sc.window_s, sc.update_every_s) == (2.0, 1.0)
    fast = config_from_mapping({"streams": {"arm": {**doc_example()["streams"]["arm"], **FAST}}})
    assert dataclasses.replace(fast, overrides=cfg.overrides) == cfg



# ------------------------------------------------------------------- the time-stamp fallbacks, live
def float64(x: float) -> bytes:
    return bytes(STORE.serialize_cdr(TY["std_msgs/msg/Float64"](data=x), "std_msgs/msg/Float64"))


F64 = f"std_msgs::msg::dds_::Float64_/{HASH}"


@pytest.fixture(scope="module")
def unstamped() -> dict[str, Any]:
    """Two streams of std_msgs/Float64 (no header.stamp) without rmw_zenoh's attachment, over real Zenoh: "zts" on
    rmw_zenoh keys from a session that timestamps its samples (Zenoh's ``timestamping/enabled``), "arr" on the
    bridge's keys from one that does not. A session of the test's own records the Zenoh timestamps it receives."""
    from streamid.daemon.service import Daemon
    from streamid.transport import Bus, ZenohSettings
    from streamid.transport.client import latest_status

    types = {"/u": "std_msgs/msg/Float64", "/y": "std_msgs/msg/Float64"}
    cfg = config_from_mapping({
        "daemon": {"workers": 1, "helper": False, "status_every_s": 0.2},
        "streams": {"zts": {**FAST, "ros2": {"inputs": ["/u:data"], "output": "/y:data", "domain_id": 7}},
                    "arr": {**FAST, "ros2": {"layout": "bridge", "key_prefix": "plain", "inputs": ["/u:data"],
                                             "output": "/y:data", "types": types}}}})
    ep = endpoint()
    n = 150
    daemon = Daemon(cfg, ZenohSettings(listen=(ep,))).start()
    out: dict[str, Any] = {"n": n, "seen": []}
    try:
        with Bus(ZenohSettings(connect=(ep,))) as plain, \
                Bus(ZenohSettings(connect=(ep,), extra=(("timestamping/enabled", "true"),))) as timed:
            assert plain.wait_connected(10) and timed.wait_connected(10)
            plain.subscribe_meta(f"7/y/{F64}", lambda k, p, t, a: out["seen"].append(t))
            time.sleep(0.3)  # the daemon's subscriptions reach these sessions
            y = 0.0
            for k in range(n):
                u = float(np.sin(0.3 * k))
                timed.put(f"7/u/{F64}", float64(u))
                plain.put("plain/u", float64(u))
                out["t_before_last_put_ns"] = time.time_ns()
                timed.put(f"7/y/{F64}", float64(y))
                plain.put("plain/y", float64(y))
                y = 0.9 * y + 0.5 * u
                time.sleep(0.005)  # about 200 Hz (nothing here depends on how steady)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                docs = {s: latest_status(plain, s, timeout_s=1.0) for s in ("zts", "arr")}
                if all(d and all(d["ros2"]["topics"][t]["received"] == n for t in ("/u", "/y")) for d in docs.values()):
                    break
                time.sleep(0.2)
            out["status"] = docs
            out["t_status_ns"] = time.time_ns()
    finally:
        daemon.stop()
    return out


@pytest.mark.parametrize(("stream", "clock"), [("zts", "zenoh timestamp"), ("arr", "arrival")])
def test_a_message_without_header_or_attachment_is_timed_by_zenoh_or_by_arrival(unstamped: dict[str, Any],
                                                                                stream: str, clock: str) -> None:
    ros2 = unstamped["status"][stream]["ros2"]
    n = unstamped["n"]
    assert ros2["bad_total"] == 0, ros2
    if stream == "zts":  # stamped when put, each input before its output: all but the last (no input after it)
        assert ros2["samples_taken"] == n - 1 and ros2["cut_before_inputs"] == 0, ros2
    else:  # two topics' callbacks run on Zenoh's threads: the first and last messages' arrival order may swap
        assert n - 2 <= ros2["samples_taken"] <= n and ros2["samples_taken"] + ros2["cut_before_inputs"] >= n - 1, ros2
    for topic in ("/u", "/y"):
        tp = ros2["topics"][topic]
        assert tp["clock"] == clock and tp["received"] == n, (topic, tp)
    # the output's last time is when its last message was sent (Zenoh's timestamp) or received (arrival): after the
    # test's clock read just before that put, before the status was read (one host: one UNIX-epoch clock)
    assert unstamped["t_before_last_put_ns"] <= ros2["topics"]["/y"]["last_t_ns"] <= unstamped["t_status_ns"]
    if stream == "zts":  # exactly the publisher's Zenoh timestamp, as another subscriber receives it
        seen = unstamped["seen"]
        assert len(seen) == n and all(t is not None for t in seen)
        assert ros2["topics"]["/y"]["last_t_ns"] == seen[-1]
