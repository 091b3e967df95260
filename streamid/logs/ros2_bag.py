"""ROS 2 bags (rosbag2: a bag directory, or its ``.mcap`` / ``.db3`` file) and CDR payloads, read with rosbags.

The only module of streamid that imports ``rosbags`` (imported on first use: ``pip install 'streamid[lab]'``); no
ROS installation is needed.  Message types are decoded from the definitions the bag carries (MCAP bags since Iron,
and bags written by rosbags or ROS 2 Jazzy+ in either storage), else from rosbags' store of the standard ROS 2
messages (:data:`TYPESTORE`: std_msgs, geometry_msgs, sensor_msgs ...); a type in neither is refused by name.

Signals are ``/topic:field.path[index]`` (:mod:`streamid.logs.ros2_fields`); a sample's time is the time the bag
recorded the message (its log time, ns), and the topics are put on the output's own timestamps by
:mod:`streamid.logs.timed`'s rule.  :class:`CdrDecoder` decodes single CDR payloads of the same types (the
payloads ROS 2 puts on Zenoh, which the daemon's ``[streams.X.ros2]`` streams decode:
:mod:`streamid.daemon.ros2_intake`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from streamid.errors import DataError
from streamid.logs.table import Table

__all__ = ["TYPESTORE", "CdrDecoder", "is_ros2_mcap", "read_bag_table", "standard_types"]

#: rosbags' store of standard message types used when a bag (or a live topic) carries no definition.
TYPESTORE = "ros2_jazzy"


def _rosbags() -> Any:
    try:
        import rosbags.highlevel
        import rosbags.typesys
    except ImportError:
        from streamid.logs.timed import needs_library

        raise needs_library("rosbags", "ROS 2 bags and CDR messages") from None
    return rosbags


def standard_types() -> Any:
    """rosbags' typestore of the standard ROS 2 messages (:data:`TYPESTORE`)."""
    rb = _rosbags()
    return rb.typesys.get_typestore(rb.typesys.Stores(TYPESTORE))


def is_ros2_mcap(path: Path) -> bool:
    """Whether an ``.mcap`` file is a ROS 2 bag (its header's profile is ``ros2``), not a streamid log."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return False
    if len(head) < 21 or not head.startswith(b"\x89MCAP0\r\n"):
        return False
    size = int.from_bytes(head[17:21], "little")
    return head[21:21 + size] == b"ros2"


def _damaged(path: Path, exc: BaseException, doing: str) -> DataError:
    from streamid.logs.timed import why_text

    return DataError(f"{path}: not a readable ROS 2 bag while {doing} ({why_text(exc)}); a "
                     "bag is a rosbag2 directory (metadata.yaml and its .mcap/.db3) or one of its files; a cut or "
                     "damaged file is not read")


def read_bag_table(path: Path, signals: Sequence[str] | None) -> Table:
    """The fields ``signals`` (inputs, then the output; ``/topic:field``) of a bag on the output's timestamps.

    Raises
    ------
    DataError
        No signals named or an unknown topic (the message lists the bag's topics), an unknown or non-numeric
        field (it lists the topic's numeric fields), a type without definition, a damaged bag, rosbags missing,
        or the grid rule's refusals (:mod:`streamid.logs.timed`).
    """
    from streamid.logs.ros2_fields import parse_signal
    from streamid.logs.timed import Signal, names_line, on_output_grid, why_text

    rb = _rosbags()
    try:
        reader = rb.highlevel.AnyReader([path], default_typestore=standard_types())
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds on a damaged bag: each is the bag's fault
        raise _damaged(path, exc, "opening it") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        listed = [f"{t} ({m})" for t, m in sorted(topics.items())]
        if not signals:
            raise DataError(f"{path}: give the signals to use, --input /topic:field (once per input) and --output "
                            "/topic:field; " + names_line(listed, "topics"))
        fields = [parse_signal(s) for s in signals]
        for f in fields:
            if f.topic not in topics:
                raise DataError(f"{path}: no topic {f.topic!r} (signal {f.text!r}); " + names_line(listed, "topics"))
            if _store(reader, topics[f.topic]) is None:
                raise DataError(f"{path}: the message type {topics[f.topic]} of {f.topic} has no definition in the "
                                f"bag nor among the standard ROS 2 messages ({TYPESTORE}); record with a ROS 2 that "
                                "stores definitions (MCAP bags, Iron or later) or add the definition")
        wanted = {f.topic for f in fields}
        times: dict[str, list[int]] = {f.text: [] for f in fields}
        values: dict[str, list[float]] = {f.text: [] for f in fields}
        conns = [c for c in reader.connections if c.topic in wanted]
        stores = {c.msgtype: _store(reader, c.msgtype) for c in conns}
        try:
            for conn, t_ns, raw in reader.messages(connections=conns):
                try:
                    msg = stores[conn.msgtype].deserialize_cdr(raw, conn.msgtype)
                except Exception as exc:  # noqa: BLE001 - a payload that is not its type's CDR
                    raise DataError(f"{path}: a message of {conn.topic} ({conn.msgtype}) logged at {t_ns} ns does not "
                                    f"decode ({why_text(exc, 120)}): a damaged bag?") from None
                for f in fields:
                    if f.topic == conn.topic:
                        try:
                            values[f.text].append(f.value(msg))
                        except DataError as exc:
                            raise DataError(f"{path}: {exc}") from None
                        times[f.text].append(int(t_ns))
        except DataError:
            raise
        except Exception as exc:  # noqa: BLE001 - a cut bag fails while reading its messages
            raise _damaged(path, exc, "reading its messages") from None
        got = []
        for f in fields:
            t = np.asarray(times[f.text], dtype=np.int64)
            if t.size == 0:
                raise DataError(f"{path}: the topic {f.topic} holds no message (signal {f.text!r})")
            order = np.argsort(t, kind="stable")
            got.append(Signal(f.text, t[order], np.asarray(values[f.text], dtype=np.float64)[order]))
        return on_output_grid(str(path), got[:-1], got[-1], {"format": "rosbag2"})
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001, S110 - closing a damaged bag: the error said is the reading's
            pass


def _store(reader: Any, msgtype: str) -> Any:
    """The typestore that defines ``msgtype``: the bag's own definitions first, else the standard messages'."""
    if msgtype in reader.typestore.fielddefs:
        return reader.typestore
    std = standard_types()
    return std if msgtype in std.fielddefs else None


class CdrDecoder:
    """Decodes CDR payloads of live ROS 2 topics (rmw_zenoh, the DDS bridge) into rosbags' message objects.

    Types come from rosbags' standard store (:data:`TYPESTORE`) plus any ``.msg`` definitions given
    (``{"pkg/msg/Name": "float64 x\\n..."}``).
    """

    def __init__(self, definitions: dict[str, str] | None = None) -> None:
        rb = _rosbags()
        self._store = standard_types()
        extra: dict[str, Any] = {}
        for name, text in (definitions or {}).items():
            try:
                extra.update(rb.typesys.get_types_from_msg(text, name))
            except Exception as exc:  # noqa: BLE001 - a definition that does not parse: the configuration's fault
                from streamid.logs.timed import why_text

                raise DataError(f"the message definition of {name} does not parse: {why_text(exc)}") from None
        if extra:
            self._store.register(extra)

    def knows(self, msgtype: str) -> bool:
        """Whether ``msgtype`` (``pkg/msg/Name``) has a definition."""
        return msgtype in self._store.fielddefs

    def decode(self, payload: bytes, msgtype: str) -> Any:
        """The message; :class:`DataError` when the payload is not ``msgtype``'s CDR."""
        try:
            return self._store.deserialize_cdr(payload, msgtype)
        except Exception as exc:  # noqa: BLE001 - any payload a publisher sends: its fault, counted by the caller
            raise DataError(f"a payload of {len(payload)} bytes is not {msgtype} in CDR ({type(exc).__name__})") from None
