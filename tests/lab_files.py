"""A lab's own files, written by the libraries the lab's tools use: asammdf (MF4), rosbags (ROS 2 bags, both
storages; CDR payloads), h5py (MATLAB v7.3). One simulated plant behind all of them, so a model can be checked.

The plant runs on the output's 100 Hz grid: y[k] = 0.6 y[k-1] + 0.8 tanh(u[k-1]) + 0.1 u[k-2], u a random
staircase (a new level every 5 output samples). The input is recorded faster (MF4: 1 kHz) or slower (ROS: 50 Hz on
/cmd_vel), each held between its samples, so the zero-order hold on the output's timestamps gives back exactly the
values the plant saw.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

OUT_PERIOD_NS = 10_000_000  # 100 Hz


def plant(n: int, seed: int = 0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, y) on the output's grid, n samples."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-2.0, 2.0, n // 5 + 1), 5)[:n]
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 0.6 * y[k - 1] + 0.8 * np.tanh(u[k - 1]) + 0.1 * u[k - 2]
    return u, y


def write_mf4(path: Path, n: int = 2000, seed: int = 0) -> Path:
    """Two channel groups: "fast" at 1 kHz (throttle_V as int16 raw counts with a linear conversion
    0.001 V/count, and temp_C), "slow" at 100 Hz (speed_rpm, and a second temp_C: a name that repeats)."""
    from asammdf import MDF, Signal

    u, y = plant(n, seed)
    t_out = np.arange(n) * (OUT_PERIOD_NS / 1e9)
    t_fast = np.arange(n * 10) * (OUT_PERIOD_NS / 1e10)
    raw = np.round(np.repeat(u, 10) * 1000).astype(np.int16)  # held between the output's samples
    mdf = MDF(version="4.10")
    mdf.append([Signal(raw, t_fast, name="throttle_V", unit="V", conversion={"a": 0.001, "b": 0.0}),
                Signal(20 + np.sin(t_fast), t_fast, name="temp_C", unit="degC")], comment="fast")
    mdf.append([Signal(1000 * y, t_out, name="speed_rpm", unit="rpm"),
                Signal(21 + np.cos(t_out), t_out, name="temp_C", unit="degC"),
                Signal(np.arange(n) % 2, t_out, name="gear_state",
                       conversion={"val_0": 0, "text_0": b"low", "val_1": 1, "text_1": b"high", "default": b"?"})],
               comment="slow")
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return path


def write_bag(path: Path, storage: str = "mcap", n: int = 2000, seed: int = 0, t0_ns: int = 1_700_000_000_000_000_000,
              definitions: bool = True) -> Path:
    """A rosbag2 bag: /cmd_vel (geometry_msgs/Twist, linear.x = u, 20 Hz: every 5th output sample), /joint_states
    (sensor_msgs/JointState, 100 Hz, velocity[2] = y), /status (std_msgs/String). ``definitions=False`` adds
    /lab_cmd of a custom type (lab_msgs/msg/Command) whose definition the bag does not hold (sqlite3 only)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    u, y = plant(n, seed)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        cmd = w.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=ts)
        if not definitions:
            from rosbags.typesys import get_types_from_msg

            ts.register(get_types_from_msg("float64 level", "lab_msgs/msg/Command"))
            custom = w.add_connection("/lab_cmd", "lab_msgs/msg/Command", typestore=ts)
        js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        st = w.add_connection("/status", "std_msgs/msg/String", typestore=ts)
        for k in range(n):
            t = t0_ns + k * OUT_PERIOD_NS
            if k % 5 == 0:  # the command changes every 5 output samples: published at 20 Hz, 1 ms ahead
                twist = T["geometry_msgs/msg/Twist"](T["geometry_msgs/msg/Vector3"](float(u[k]), 0.0, 0.0),
                                                     T["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.1))
                w.write(cmd, t - 1_000_000, ts.serialize_cdr(twist, "geometry_msgs/msg/Twist"))
                if not definitions:
                    w.write(custom, t, ts.serialize_cdr(ts.types["lab_msgs/msg/Command"](float(u[k])),
                                                        "lab_msgs/msg/Command"))
            stamp = T["builtin_interfaces/msg/Time"](sec=int(t // 10**9), nanosec=int(t % 10**9))
            msg = T["sensor_msgs/msg/JointState"](
                T["std_msgs/msg/Header"](stamp, "base"), ["j0", "j1", "j2"], np.array([0.0, 0.1, 0.2]),
                np.array([0.0, 1.0, float(y[k])]), np.zeros(3))
            w.write(js, t + 2_000_000, ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
            if k % 100 == 0:
                w.write(st, t, ts.serialize_cdr(T["std_msgs/msg/String"]("ok"), "std_msgs/msg/String"))
    if not definitions:  # as a bag of a ROS 2 that stored no definitions (sqlite3 before Jazzy): none for lab_msgs
        import sqlite3

        assert storage == "sqlite3", "definitions=False is written as an sqlite3 bag"
        con = sqlite3.connect(next(path.glob("*.db3")))
        con.execute("DELETE FROM message_definitions WHERE topic_type = 'lab_msgs/msg/Command'")
        con.commit()
        con.close()
    return path


def write_mat73(path: Path, n: int = 2000, seed: int = 0) -> Path:
    """A MATLAB v7.3 file as MATLAB writes it (512-byte header, HDF5, MATLAB_class attributes, arrays transposed):
    u and y (N x 1), X (N x 2: columns u and y), a struct s with fields u and y, and a char variable."""
    import h5py

    u, y = plant(n, seed)
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, a in (("u", u[None, :]), ("y", y[None, :]), ("X", np.vstack([u, y]))):
            d = f.create_dataset(name, data=a)
            d.attrs["MATLAB_class"] = np.bytes_("double")
        g = f.create_group("s")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        for name, a in (("u", u), ("y", y)):
            d = g.create_dataset(name, data=a[None, :])
            d.attrs["MATLAB_class"] = np.bytes_("double")
        c = f.create_dataset("label", data=np.frombuffer(b"bench", dtype=np.uint8).astype(np.uint16)[None, :])
        c.attrs["MATLAB_class"] = np.bytes_("char")
    return matlab_header(path)


def matlab_header(path: Path) -> Path:
    """MATLAB's 128-byte v7.3 header written into the 512-byte user block of an HDF5 file (``userblock_size=512``)."""
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(head.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM" + b"\x00" * (512 - 128))
    return path
