"""Command help as plain text: the module docstrings argparse shows are written in reStructuredText.

:func:`plain` turns the markup a terminal reader would see literally into plain text:
````code```` becomes ``code``, a ``Heading`` underlined with ``---`` becomes ``Heading:``,
a lone ``::`` line disappears and a trailing ``::`` becomes ``:``, roles such as
``:class:`~a.b.C``` become ``C``.
"""

from __future__ import annotations

import argparse
import re

__all__ = ["plain", "plain_parser"]

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):`~?(?:[\w.]*\.)?([^`]+)`")
_LITERAL = re.compile(r"``([^`]+)``")
#: The reST literal-block marker at the end of a line (two colons).
_LITERAL_MARK = re.compile(r":{2}$")
_UNDERLINE = re.compile(r"^\s*([-=~^])\1{2,}\s*$")


def plain(text: str | None) -> str | None:
    """``text`` without reStructuredText markup (None stays None)."""
    if not text:
        return text
    text = _ROLE.sub(r"\1", text)
    text = _LITERAL.sub(r"\1", text)
    out: list[str] = []
    for line in text.splitlines():
        if _UNDERLINE.match(line) and out and out[-1].strip():
            out[-1] = out[-1].rstrip() + ":"
            continue
        if _LITERAL_MARK.fullmatch(line.strip()):  # a line that is only the reST literal-block marker
            continue
        if _LITERAL_MARK.search(line.rstrip()):  # "Example::" -> "Example:"
            line = line.rstrip()[:-1]
        out.append(line)
    return "\n".join(out)


def plain_parser(parser: argparse.ArgumentParser) -> None:
    """Clean the description, epilog and every argument's help of ``parser`` in place."""
    parser.description = plain(parser.description)
    parser.epilog = plain(parser.epilog)
    for action in parser._actions:
        if isinstance(action.help, str):
            action.help = plain(action.help)
