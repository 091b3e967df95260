"""Names that came from the network, made safe to check and to show.

A channel, output or daemon name is chosen by whoever publishes.  Control, format and
bidirectional-override characters (e.g. U+202E RIGHT-TO-LEFT OVERRIDE, which makes
``"y\\u202e1v"`` *display* as ``y v1``) let a publisher make a terminal line or a log say
something else than it holds.  :func:`unsafe_char` finds them; the sample codec refuses
channel names holding one, and :func:`printable` escapes them (and the backslash, so an
escaped name never looks like another name) wherever such text is shown.
"""

from __future__ import annotations

import unicodedata

__all__ = ["MAX_NAME_BYTES", "UNSAFE_CATEGORIES", "UNSAFE_RULE", "printable", "unsafe_char"]

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
