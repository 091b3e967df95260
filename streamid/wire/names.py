"""Names that came from the network, made safe to check and to show.

A channel, output or daemon name is chosen by whoever publishes.  Control, format and
bidirectional-override characters (e.g. U+202E RIGHT-TO-LEFT OVERRIDE, which makes
``"y\\u202e1v"`` *display* as ``y v1``) let a publisher make a terminal line or a log say
something else than it holds.  :func:`unsafe_char` finds them; the sample codec refuses
channel names holding one, and :func:`printable` escapes them (and the backslash, so an
escaped name never looks like another name) wherever such text is shown.

A model's signal names (its inputs and its output) follow one rule on every path a model takes (the model
reader, ``streamid export``, ``watch --save-fmu``, the wire): :func:`check_signal_names`.  Each name is what
an FMI 2.0 variable name in the flat convention and XML 1.0 accept and a terminal shows as it is
(:data:`NAME_RULE`); the names of a model (of an export: of all its models) are distinct and never one of
the variables streamid adds per output (:func:`added_names`).  C never sees a name but inside a comment:
the generated code's identifiers are made from the export's name and indices, never from signal names.
"""

from __future__ import annotations

import unicodedata
from collections.abc import Mapping, Sequence

from streamid.errors import ModelFormatError

__all__ = ["MAX_NAME_BYTES", "NAME_RULE", "UNSAFE_CATEGORIES", "UNSAFE_RULE", "added_names", "check_signal_names",
           "name_problem", "printable", "unsafe_char"]

#: Longest accepted channel or output name, in UTF-8 bytes.
MAX_NAME_BYTES = 256

#: Unicode general categories refused in names: control (Cc), format (Cf, which holds the
#: bidirectional overrides and zero-width characters), line and paragraph separators (Zl, Zp),
#: private use (Co) and surrogates (Cs).
UNSAFE_CATEGORIES: frozenset[str] = frozenset({"Cc", "Cf", "Zl", "Zp", "Co", "Cs"})
#: The rule, in words, for error messages.
UNSAFE_RULE = (
    "no control characters, format or bidirectional-override characters, line or paragraph separators, "
    "private-use characters or surrogates (Unicode categories Cc, Cf, Zl, Zp, Co, Cs; e.g. U+202E)"
)
#: A signal name, in words (:func:`name_problem`).
NAME_RULE = (f"1 to {MAX_NAME_BYTES} UTF-8 bytes with {UNSAFE_RULE}, and no noncharacter (U+FDD0..U+FDEF, "
             "U+FFFE, U+FFFF and the last two of every plane: XML 1.0 refuses U+FFFE and U+FFFF)")
#: Shown escaped: the unsafe categories and unassigned code points (Cn).
_ESCAPED = UNSAFE_CATEGORIES | {"Cn"}


def unsafe_char(text: str) -> tuple[int, str] | None:
    """``(index, character)`` of the first character of ``text`` in :data:`UNSAFE_CATEGORIES`, or None."""
    if text.isprintable():  # fast path: no Cc, Cf, Cs, Co, Cn, Zl, Zp (nor Zs but the space)
        return None
    for i, c in enumerate(text):
        if unicodedata.category(c) in UNSAFE_CATEGORIES:
            return i, c
    return None


def _escape(c: str) -> str:
    n = ord(c)
    if n < 0x100:
        return f"\\x{n:02x}"
    if n < 0x10000:
        return f"\\u{n:04x}"
    return f"\\U{n:08x}"


def printable(text: object, max_chars: int | None = None) -> str:
    """``text`` safe to print on one line: unsafe characters and ``\\`` escaped as in Python literals.

    Letters, digits, punctuation and symbols of every script are kept as they are
    (``"force_N"``, ``"Weg_µm"``, ``"温度"``); control, format, bidi-override, separator,
    private-use, surrogate and unassigned characters become ``\\xNN``, ``\\uNNNN`` or
    ``\\UNNNNNNNN``, and ``\\`` becomes ``\\\\``, so two different names never print alike.
    A non-str is shown through ``str()`` first.  With ``max_chars``, a longer result is cut
    and ends with ``...``.

    >>> printable("f\\u202e")
    'f\\\\u202e'
    >>> printable("a\\nb")
    'a\\\\x0ab'
    """
    s = text if isinstance(text, str) else str(text)
    out = "".join(
        "\\\\" if c == "\\" else _escape(c) if unicodedata.category(c) in _ESCAPED else c for c in s
    )
    if max_chars is not None and len(out) > max_chars:
        out = out[: max(0, max_chars - 3)] + "..."
    return out


def _nonchar(c: str) -> bool:
    n = ord(c)
    return 0xFDD0 <= n <= 0xFDEF or (n & 0xFFFE) == 0xFFFE


def name_problem(value: object) -> str | None:
    """Why ``value`` is not a signal name (:data:`NAME_RULE`), in words naming the character (``"holds U+000A at
    position 1"``); None if it is one."""
    if not isinstance(value, str):
        return f"must be a string; got {type(value).__name__} {printable(repr(value), 80)}"
    size = len(value.encode("utf-8", "surrogatepass"))
    if not 1 <= size <= MAX_NAME_BYTES:
        return f"must be 1 to {MAX_NAME_BYTES} UTF-8 bytes; got {size} bytes"
    bad = unsafe_char(value)
    if bad is None:
        bad = next(((i, c) for i, c in enumerate(value) if _nonchar(c)), None)
    if bad is not None:
        return f"holds U+{ord(bad[1]):04X} at position {bad[0]}"
    return None


def added_names(output: str) -> tuple[str, ...]:
    """The variables streamid adds for an output: ``initial_<output>`` (the FMU's initial value) and, reserved for
    the interval and domain outputs, ``<output>_lower``, ``<output>_upper``, ``<output>_in_domain``."""
    return (f"initial_{output}", f"{output}_lower", f"{output}_upper", f"{output}_in_domain")


def check_signal_names(inputs: Sequence[object], outputs: Sequence[object], where: str = "model field",
                       error: type[Exception] = ModelFormatError) -> None:
    """Refuse names that break the one rule: each input and output a name (:data:`NAME_RULE`), all distinct, and
    none the variable streamid adds for an output (:func:`added_names`).

    Raises
    ------
    ModelFormatError
        (or ``error``) One line naming the field (``where 'inputs'[1]``, ``where 'output'``; with several outputs
        ``where 'outputs'[j]``), the name (escaped) and the character or the clash.
    """
    fields = [(f"'inputs'[{i}]", v) for i, v in enumerate(inputs)]
    fields += [("'output'" if len(outputs) == 1 else f"'outputs'[{j}]", v) for j, v in enumerate(outputs)]
    for field, v in fields:
        problem = name_problem(v)
        if problem is not None:
            shown = f" '{printable(v, 120)}'" if isinstance(v, str) else ""
            raise error(f"{where} {field}{shown} {problem}: a signal name is {NAME_RULE}")
    seen: dict[str, str] = {}
    for field, v in fields:
        name = str(v)
        if name in seen:
            raise error(f"{where} {field} '{printable(name, 120)}' is also {seen[name]}: a model's signal names must "
                        "be distinct (they are the FMU's variable names)")
        seen[name] = field
    for field, v in fields[len(inputs):]:
        for extra in added_names(str(v)):
            if extra in seen:
                raise error(
                    f"{where} {seen[extra]} '{printable(extra, 120)}' is a name streamid adds for the output "
                    f"'{printable(v, 120)}' ({field}): initial_<output>, <output>_lower, <output>_upper and "
                    "<output>_in_domain are reserved")


def check_model_names(doc: object) -> None:
    """:func:`check_signal_names` on a parsed model document's ``inputs`` and ``output`` (absent: the names the
    model reader gives, ``u0, u1, ...`` per input of its normalisation and ``y``); other malformed fields are
    left to the model's parser."""
    if not isinstance(doc, Mapping):
        return
    inputs = doc.get("inputs")
    if not inputs:
        norm = doc.get("normalisation")
        low = norm.get("u_low") if isinstance(norm, Mapping) else None
        inputs = [f"u{i}" for i in range(len(low))] if isinstance(low, list) else []
    if isinstance(inputs, list):
        check_signal_names(inputs, [doc.get("output", "y")])
