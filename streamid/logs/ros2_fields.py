"""ROS 2 signals named the way their users name them: ``/topic:field.path[index]``.

``/cmd_vel:linear.x`` is the ``linear.x`` field of the messages on ``/cmd_vel``; ``/joint_states:velocity[2]`` the
third element of ``velocity``; ``/imu:orientation.w``, ``/tf:transforms[0].transform.translation.x``.  A field is
reached on a decoded message (rosbags' message classes: attributes, numpy arrays, lists) and must be a number
(``bool``, an integer or a float type of the message definition).  Nothing here imports rosbags.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from streamid.errors import DataError

__all__ = ["FieldPath", "parse_signal", "numeric_fields", "SIGNAL_FORM"]

SIGNAL_FORM = "/topic:field.path[index], e.g. /cmd_vel:linear.x or /joint_states:velocity[2]"
_TOPIC = re.compile(r"^(/?[A-Za-z~][A-Za-z0-9_/~{}]*)$")
_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")
#: Fields listed at most when naming what a message holds (a large array is shown by its first elements).
_LIST_ELEMENTS = 4


@dataclass(frozen=True)
class FieldPath:
    """A signal: its topic and the steps to its field (attribute names and indices)."""

    text: str
    topic: str
    steps: tuple[str | int, ...]

    def value(self, msg: Any) -> float:
        """The field's value on ``msg``; :class:`DataError` when it is missing or not a number (the message says
        which step failed)."""
        v: Any = msg
        done = self.topic + ":"
        for step in self.steps:
            if isinstance(step, int):
                try:
                    v = v[step]
                except (IndexError, TypeError, KeyError):
                    size = len(v) if hasattr(v, "__len__") else None
                    raise DataError(f"{self.text}: {done} has {size if size is not None else 'no'} elements; "
                                    f"index {step} is out of range") from None
                done += f"[{step}]"
            else:
                if step.startswith("_") or not hasattr(v, step) or callable(getattr(v, step)):
                    raise DataError(f"{self.text}: no field {step!r} in {done.rstrip(':.')}; "
                                    + _fields_text(msg, self.topic))
                v = getattr(v, step)
                done += ("" if done.endswith(":") else ".") + step
        if isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating)):
            return float(v)
        kind = "an array (give an index, e.g. [0])" if isinstance(v, (np.ndarray, list, tuple)) else \
            f"a {type(v).__name__.split('__')[-1]}"
        raise DataError(f"{self.text}: the field is {kind}, not a number; " + _fields_text(msg, self.topic))


def parse_signal(text: str) -> FieldPath:
    """``/topic:field.path[i]`` as a :class:`FieldPath`; :class:`DataError` giving the form if malformed."""
    topic, sep, path = text.partition(":")
    if not sep or not _TOPIC.match(topic) or not path:
        raise DataError(f"a ROS 2 signal is {SIGNAL_FORM}; got {text!r}")
    steps: list[str | int] = []
    for part in path.split("."):
        m = _STEP.fullmatch(part)
        if m is None:
            raise DataError(f"a ROS 2 signal is {SIGNAL_FORM}; {part!r} of {text!r} is not a field name with "
                            "optional [index]")
        steps.append(m.group(1))
        steps += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return FieldPath(text, topic if topic.startswith("/") else "/" + topic, tuple(steps))


def _fields(v: Any, prefix: str, out: list[str], limit: int, depth: int = 0) -> None:
    if len(out) >= limit or depth > 8:
        return
    if isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating)):
        out.append(prefix)
        return
    if isinstance(v, np.ndarray):
        if v.dtype.kind in "biuf":
            out.extend(f"{prefix}[{i}]" for i in range(min(v.size, _LIST_ELEMENTS)))
        return
    if isinstance(v, (list, tuple)):
        for i, x in enumerate(v[:_LIST_ELEMENTS]):
            _fields(x, f"{prefix}[{i}]", out, limit, depth + 1)
        return
    names = getattr(v, "__dataclass_fields__", None) or getattr(v, "__slots__", None) or ()
    for name in names:
        if not name.startswith("_"):
            _fields(getattr(v, name, None), f"{prefix}.{name}" if prefix else name, out, limit, depth + 1)


def numeric_fields(msg: Any, limit: int = 200) -> list[str]:
    """The numeric field paths of a decoded message (arrays by their first elements), at most ``limit``."""
    out: list[str] = []
    _fields(msg, "", out, limit)
    return out


def _fields_text(msg: Any, topic: str) -> str:
    from streamid.logs.timed import names_line

    return names_line([f"{topic}:{f}" for f in numeric_fields(msg)], f"numeric fields of {topic}'s message")
