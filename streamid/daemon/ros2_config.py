"""A stream's ``[streams.X.ros2]`` table: which ROS 2 topics on Zenoh give its input and output fields.

Two key layouts (docs/daemon.md, "ROS 2 topics"):

* ``rmw_zenoh`` (rmw_zenoh_cpp 0.2+, ROS 2 Jazzy and later; its docs/design.md): a topic is published on
  ``<domain_id>/<topic without its leading slash>/<type>/<type hash>``, e.g.
  ``0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_...``; the daemon subscribes to
  ``<domain_id>/<topic>/<type>/*`` when the topic's type is configured, else ``<domain_id>/<topic>/*/*`` and reads
  the type from the key.
* ``bridge`` (zenoh-bridge-ros2dds): ``<key_prefix/><topic without its leading slash>``; the key does not say the
  type, so every topic's type must be configured (``[streams.X.ros2.types]``).

Payloads are CDR (a 4-byte encapsulation header, then the message), decoded with rosbags
(:class:`streamid.logs.ros2_bag.CdrDecoder`).  Signals are named as for bags, ``/topic:field.path[index]``
(:mod:`streamid.logs.ros2_fields`); nothing here imports rosbags.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from streamid.errors import ConfigError, DataError

__all__ = ["LAYOUTS", "CLOCKS", "Ros2Source", "ros2_from_table", "ros2_toml", "dds_type", "ros_type"]

LAYOUTS = ("rmw_zenoh", "bridge")
#: ``stamp``: header.stamp, else the publisher's time (rmw_zenoh's attachment, Zenoh's timestamp), else arrival.
CLOCKS = ("stamp", "arrival")
_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/msg/([A-Za-z][A-Za-z0-9_]*)$")
_DDS = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)::msg::dds_::([A-Za-z][A-Za-z0-9_]*)_$")
_PREFIX = re.compile(r"^[A-Za-z0-9_~-]+(/[A-Za-z0-9_~-]+)*$")
_KEYS: dict[str, str] = {
    "layout": f"one of {', '.join(LAYOUTS)}",
    "domain_id": "an integer in [0, 232] (ROS_DOMAIN_ID)",
    "inputs": "a list of ROS 2 signals /topic:field.path[index]",
    "output": "a ROS 2 signal /topic:field.path[index]",
    "key_prefix": "a Zenoh key prefix without wildcards, e.g. \"robot1\" (bridge layout only)",
    "clock": f"one of {', '.join(CLOCKS)}",
    "types": "a table of topic = \"pkg/msg/Name\"",
    "max_pending": "an integer number of samples per signal in [2, 1000000]",
    "max_keys_per_topic": "an integer in [1, 64]",
    "max_message_bytes": "an integer number of bytes in [64, 2147483648]",
}


def dds_type(msgtype: str) -> str:
    """``geometry_msgs/msg/Twist`` as rmw_zenoh writes it in a key: ``geometry_msgs::msg::dds_::Twist_``."""
    m = _TYPE.match(msgtype)
    if m is None:
        raise ConfigError(f"a ROS 2 message type is pkg/msg/Name, e.g. geometry_msgs/msg/Twist; got {msgtype!r}")
    return f"{m.group(1)}::msg::dds_::{m.group(2)}_"


def ros_type(chunk: str) -> str | None:
    """The ``pkg/msg/Name`` of an rmw_zenoh key's type chunk (None: not a message type's DDS name)."""
    m = _DDS.match(chunk)
    return None if m is None else f"{m.group(1)}/msg/{m.group(2)}"


@dataclass(frozen=True)
class Ros2Source:
    """Where one stream's signals come from (see the module docstring); every bound has a default."""

    inputs: tuple[str, ...]
    output: str
    layout: str = "rmw_zenoh"
    domain_id: int = 0
    key_prefix: str = ""
    clock: str = "stamp"
    #: ``(topic, pkg/msg/Name)`` pairs (required for every topic with the bridge layout)
    types: tuple[tuple[str, str], ...] = ()
    #: samples one signal may hold waiting for the grid (the output's next time, or every input to pass it)
    max_pending: int = 10_000
    #: distinct keys (type, type hash) accepted per topic; the rest are counted and ignored
    max_keys_per_topic: int = 4
    #: a larger payload is not copied out of Zenoh nor decoded (counted)
    max_message_bytes: int = 1 << 20

    def __post_init__(self) -> None:
        from streamid.logs.ros2_fields import parse_signal

        if self.layout not in LAYOUTS:
            raise ConfigError(f"ros2.layout must be {_KEYS['layout']}; got {self.layout!r}")
        if self.clock not in CLOCKS:
            raise ConfigError(f"ros2.clock must be {_KEYS['clock']}; got {self.clock!r}")
        for key, lo, hi in (("domain_id", 0, 232), ("max_pending", 2, 1_000_000), ("max_keys_per_topic", 1, 64),
                            ("max_message_bytes", 64, 2**31)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"ros2.{key} must be {_KEYS[key]}; got {v!r}")
        if not self.inputs:
            raise ConfigError("ros2.inputs must name at least one ROS 2 signal, e.g. [\"/cmd_vel:linear.x\"]; got none")
        if self.key_prefix and (self.layout != "bridge" or not _PREFIX.match(self.key_prefix)):
            raise ConfigError(f"ros2.key_prefix must be {_KEYS['key_prefix']}; got {self.key_prefix!r}")
        try:
            signals = [parse_signal(s) for s in (*self.inputs, self.output)]
        except DataError as exc:
            raise ConfigError(f"ros2: {exc}") from None
        texts = [s.text for s in signals]
        if len(set(texts)) != len(texts):
            raise ConfigError(f"ros2: each signal may be named once (inputs and output); got {texts}")
        typed = dict(self.types)
        for topic, msgtype in self.types:
            dds_type(msgtype)
            if topic not in {s.topic for s in signals}:
                raise ConfigError(f"ros2.types names topic {topic!r}, which no signal uses; topics: "
                                  f"{', '.join(self.topics())}")
        if self.layout == "bridge":
            missing = [t for t in self.topics() if t not in typed]
            if missing:
                raise ConfigError(f"ros2: the bridge layout's keys do not say a topic's type: give it in "
                                  f"[streams.X.ros2.types] for {', '.join(missing)} (e.g. \"{missing[0]}\" = "
                                  "\"geometry_msgs/msg/Twist\")")

    def topics(self) -> tuple[str, ...]:
        """The topics of the signals (with their leading slash), each once, inputs first."""
        from streamid.logs.ros2_fields import parse_signal

        return tuple(dict.fromkeys(parse_signal(s).topic for s in (*self.inputs, self.output)))

    def type_of(self, topic: str) -> str | None:
        """The configured ``pkg/msg/Name`` of ``topic`` (None: read from the rmw_zenoh key)."""
        return dict(self.types).get(topic)

    def key_expr(self, topic: str) -> str:
        """The Zenoh key expression subscribed for ``topic``."""
        name = topic.lstrip("/")
        if self.layout == "bridge":
            return f"{self.key_prefix}/{name}" if self.key_prefix else name
        msgtype = self.type_of(topic)
        return f"{self.domain_id}/{name}/{dds_type(msgtype) if msgtype else '*'}/*"

    def topic_of(self, key: str) -> tuple[str, str | None] | None:
        """``(topic, message type)`` of a received key (type None: not a message type); None: not one of ours."""
        for topic in self.topics():
            name = topic.lstrip("/")
            if self.layout == "bridge":
                if key == (f"{self.key_prefix}/{name}" if self.key_prefix else name):
                    return topic, self.type_of(topic)
                continue
            head = f"{self.domain_id}/{name}/"
            rest = key[len(head):].split("/") if key.startswith(head) else []
            if len(rest) == 2:
                return topic, ros_type(rest[0])
        return None


def ros2_from_table(where: str, table: Any) -> Ros2Source:
    """A ``[where]`` table (``streams.X.ros2``) as a :class:`Ros2Source`; unknown keys and wrong types refused."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{where}] must be a table (layout, domain_id, inputs, output, ...); got {table!r}")
    extra = sorted(set(table) - set(_KEYS))
    if extra:
        raise ConfigError(f"unknown key {where}.{extra[0]!r}; accepted keys in [{where}]: {', '.join(sorted(_KEYS))}")
    kw: dict[str, Any] = {}
    for key, value in table.items():
        bad = ConfigError(f"{where}.{key} must be {_KEYS[key]}; got {value!r}")
        if key == "inputs":
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise bad
            kw[key] = tuple(value)
        elif key == "types":
            if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
                raise bad
            kw[key] = tuple(sorted((t if t.startswith("/") else "/" + t, v) for t, v in value.items()))
        elif key in ("output", "layout", "key_prefix", "clock"):
            if not isinstance(value, str):
                raise bad
            kw[key] = value
        elif isinstance(value, bool) or not isinstance(value, int) or not math.isfinite(value):
            raise bad
        else:
            kw[key] = value
    if "output" not in kw or "inputs" not in kw:
        raise ConfigError(f"[{where}] must give inputs = [\"/topic:field\", ...] and output = \"/topic:field\"")
    try:
        return Ros2Source(**kw)
    except ConfigError as exc:
        raise ConfigError(f"[{where}]: {exc}") from None


def ros2_toml(name: str, src: Ros2Source) -> list[str]:
    """The ``[name]`` table (and its ``types`` table) that :func:`ros2_from_table` reads back to ``src``."""
    import json

    lines = [f"[{name}]", f"layout = {json.dumps(src.layout)}", f"domain_id = {src.domain_id}",
             "inputs = [" + ", ".join(json.dumps(s) for s in src.inputs) + "]", f"output = {json.dumps(src.output)}",
             f"clock = {json.dumps(src.clock)}", f"max_pending = {src.max_pending}",
             f"max_keys_per_topic = {src.max_keys_per_topic}", f"max_message_bytes = {src.max_message_bytes}"]
    if src.key_prefix:
        lines.append(f"key_prefix = {json.dumps(src.key_prefix)}")
    if src.types:
        lines += ["", f"[{name}.types]", *(f"{json.dumps(t)} = {json.dumps(m)}" for t, m in src.types)]
    return lines
