"""Read a CSV (or other delimited text) data file: delimiter, decimal comma, missing cells, file line numbers.

Rules (the ``streamid identify`` help and docs/method.md say the same):

* **Header**: the first non-empty line holds the column names (a leading ``#`` is
  stripped, as ``numpy.savetxt`` writes it).
* **Delimiter**: ``,`` ``;`` tab ``|`` or whitespace, found by :class:`csv.Sniffer`
  over the header and the first :data:`SNIFF_LINES` lines, kept if the header then has
  >= 2 fields and at least half of those lines as many; otherwise each candidate is
  tried so, in that order, whitespace last.  ``delimiter=`` overrides.
* **Decimal comma**: with a delimiter other than ``,``, numbers written ``1,5`` are
  read as 1.5 when the first lines hold such numbers and no ``.`` decimal point.
  A comma-separated file cannot have decimal commas (the fields would be ambiguous).
* **Missing values**: an empty cell, ``NaN``, ``NA``, ``N/A``, ``null`` or ``None``
  (any case) is read as NaN; the caller decides (:func:`streamid.logs.datafile.load_dataset`:
  an error naming the rows, ``--drop`` or ``--fill``).  Anything else that is not a
  number is an error naming the column, the file line and the value.
* **Text**: UTF-8 (a byte-order mark is skipped); UTF-16 and UTF-32 with a byte-order mark are
  read too; other bytes are an error naming the encoding to save in.  A line longer than
  :data:`MAX_LINE_CHARS` is an error (the file is read line by line: memory stays bounded).
* **Clock**: a column named like a time (``t``, ``time``, ``timestamp``, with an
  optional unit suffix ``_s``, ``_ms``, ``_us``, ``_ns``; seconds without one), whose
  values are all numbers and strictly increasing, gives the samples' times.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError

__all__ = [
    "DELIMITER_NAMES",
    "MISSING_TOKENS",
    "MAX_LINE_CHARS",
    "SNIFF_LINES",
    "parse_delimiter",
    "detect_delimiter",
    "read_delimited",
    "time_unit_ns",
    "clock_of",
]

#: Longest line read (characters); a longer one stops the file with an error (1 MiB: ~50,000 numbers).
MAX_LINE_CHARS = 1 << 20
#: Lines (after the header) the delimiter and decimal mark are judged on.
SNIFF_LINES = 50
#: Accepted delimiters and their names (``" "`` means any run of whitespace).
DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", "|": "pipe", " ": "whitespace"}
_ALIASES = {
    ",": ",", "comma": ",", ";": ";", "semicolon": ";", "\t": "\t", "\\t": "\t", "tab": "\t", "|": "|", "pipe": "|",
    " ": " ", "space": " ", "whitespace": " ",
}
#: Cells read as a missing value (compared in lower case, surrounding blanks stripped).
MISSING_TOKENS = frozenset({"", "nan", "na", "n/a", "null", "none"})
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_TIME_NAME = re.compile(r"^(t|time|timestamp|zeit|tiempo)(_(s|sec|ms|us|ns))?$", re.IGNORECASE)
_UNIT_NS = {"s": 10**9, "sec": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}


def parse_delimiter(text: str) -> str:
    """A ``--delimiter`` value: ``,`` ``;`` ``tab`` (or ``\\t``) ``|`` or ``space``/``whitespace``."""
    d = _ALIASES.get(text) or _ALIASES.get(text.strip().lower())
    if d is None:
        raise DataError(
            f"--delimiter must be one of ',' ';' 'tab' '|' 'whitespace' (or 'comma', 'semicolon', 'pipe', 'space'); "
            f"got {text!r}"
        )
    return d


def _split(line: str, delimiter: str) -> list[str]:
    if delimiter == " ":
        return line.split()
    return next(csv.reader([line], delimiter=delimiter))


def detect_delimiter(header: str, lines: list[str], where: str) -> str:
    """The delimiter of a header and its first data lines (see the module's rules)."""
    sample = [header, *lines[:SNIFF_LINES]]
    order: list[str] = []
    try:
        order.append(csv.Sniffer().sniff("\n".join(sample), delimiters=",;\t|").delimiter)
    except csv.Error:
        pass
    order += [d for d in (",", ";", "\t", "|", " ") if d not in order]
    for d in order:
        h = len(_split(header, d))
        if h >= 2 and 2 * sum(len(_split(ln, d)) == h for ln in sample[1:]) >= len(sample) - 1:
            return d
    raise DataError(
        f"{where}: cannot tell the delimiter: with none of comma, semicolon, tab, pipe or whitespace do the header "
        f"and at least half of the first {len(sample) - 1} data lines have the same number (>= 2) of fields; pass "
        "--delimiter (',' ';' 'tab' '|' 'whitespace'), or check the header names every column"
    )


def _decimal_comma(rows: list[list[str]]) -> bool:
    cells = [c.strip() for r in rows[:SNIFF_LINES] for c in r]
    return any(_DECIMAL_COMMA.match(c) for c in cells) and not any("." in c for c in cells)


def time_unit_ns(name: str) -> int | None:
    """Nanoseconds per unit of a time column named ``name`` (``time_s`` -> 1e9, ``t_ms`` -> 1e6), None if not time-like."""
    m = _TIME_NAME.match(name.strip())
    if m is None:
        return None
    return _UNIT_NS[m.group(3).lower()] if m.group(3) else 10**9


def clock_of(columns: dict[str, NDArray[np.float64]]) -> tuple[str, NDArray[np.int64]] | None:
    """The first time-like column whose values are all numbers and strictly increasing, as integer ns."""
    for name, v in columns.items():
        unit = time_unit_ns(name)
        if unit is None or v.size < 2 or not np.all(np.isfinite(v)) or not np.all(np.diff(v) > 0):
            continue
        scaled = v * float(unit)
        if not np.all(np.abs(scaled) < 9e18):  # beyond int64 ns (~292 years): not a clock in this unit
            continue
        t_ns = np.round(scaled).astype(np.int64)
        if np.all(np.diff(t_ns) > 0):
            return name, t_ns
    return None


def _encoding(head: bytes) -> str:
    if head.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "utf-32"
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "utf-16"
    return "utf-8-sig"


def _text_lines(path: Path) -> list[str]:
    """The file's lines (see the module's rules on text), read line by line, none longer than MAX_LINE_CHARS."""
    try:
        with open(path, "rb") as fb:
            head = fb.read(64)
        enc = _encoding(head)
        if enc == "utf-8-sig" and b"\x00" in head:
            raise DataError(f"{path}: holds NUL bytes, which no text CSV has (UTF-16 without a byte-order mark?): "
                            "save it as UTF-8 (UTF-16 or UTF-32 with a byte-order mark are read too)")
        lines: list[str] = []
        with open(path, newline="", encoding=enc) as fh:
            while ln := fh.readline(MAX_LINE_CHARS + 1):
                if len(ln) > MAX_LINE_CHARS:
                    raise DataError(f"{path}: line {len(lines) + 1} is longer than {MAX_LINE_CHARS} characters; a CSV "
                                    "row holds one sample of every column (is this a CSV file?)")
                lines.extend(ln.splitlines())
    except OSError as exc:
        raise DataError(f"cannot read CSV file {path}: {exc}") from None
    except UnicodeDecodeError as exc:
        bad = exc.object[exc.start : exc.start + 1].hex()
        raise DataError(
            f"{path}: is not {'UTF-8' if enc == 'utf-8-sig' else enc.upper()} text (byte 0x{bad} cannot be decoded): "
            "save it as UTF-8 (UTF-16 or UTF-32 with a byte-order mark are read too)"
        ) from None
    return lines


def read_delimited(
    path: Path, delimiter: str | None = None
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.int64], dict[str, str], dict[str, str]]:
    """Columns (NaN where a cell is missing), the 1-based file line of every row, how the file was read, and why
    each unreadable column cannot be used.

    Returns
    -------
    columns, lines, how, unreadable
        ``how`` holds ``delimiter`` (its name), ``decimal`` (``"."`` or ``","``). ``unreadable`` maps a column
        holding a cell that is neither a number nor a missing value to the error naming its first such cell:
        it is raised only if the column is used (a notes column beside the signals does not stop a file).

    Raises
    ------
    DataError
        Unreadable file, no header or data, duplicate names, a row with another number of
        fields than the header.
    """
    raw = _text_lines(path)
    numbered = [(i + 1, ln) for i, ln in enumerate(raw) if ln.strip()]
    if len(numbered) < 2:
        raise DataError(f"{path}: a CSV file needs a header row with column names and at least one data row")
    header_line = numbered[0][1].lstrip()
    if header_line.startswith("#"):
        header_line = header_line[1:]
    body = numbered[1:]
    d = detect_delimiter(header_line, [ln for _, ln in body], str(path)) if delimiter is None else delimiter
    header = [h.strip() for h in _split(header_line, d)]
    if len(set(header)) != len(header) or any(not h for h in header):
        raise DataError(
            f"{path}: the header row must hold distinct, non-empty column names; got {header} "
            f"(read with delimiter {DELIMITER_NAMES[d]}; --delimiter sets another)"
        )
    if len(header) < 2:
        raise DataError(
            f"{path}: the header {header_line.strip()!r} gives one column with delimiter {DELIMITER_NAMES[d]}; "
            "a model needs an input and an output column (--delimiter sets the delimiter)"
        )
    rows = []
    for line_no, ln in body:
        r = _split(ln, d)
        if len(r) != len(header):
            raise DataError(
                f"{path}: line {line_no} has {len(r)} fields; the header has {len(header)} "
                f"(delimiter {DELIMITER_NAMES[d]}): {ln[:80]!r}"
            )
        rows.append(r)
    comma = d != "," and _decimal_comma(rows)
    cols: dict[str, NDArray[np.float64]] = {}
    unreadable: dict[str, str] = {}
    for j, name in enumerate(header):
        vals = np.empty(len(rows))
        for i, r in enumerate(rows):
            cell = r[j].strip()
            if cell.lower() in MISSING_TOKENS:
                vals[i] = np.nan
                continue
            try:
                vals[i] = float(cell.replace(",", ".") if comma else cell)
            except ValueError:
                hint = ""
                if "," in cell and not comma:
                    hint = " (a decimal comma? it is read only in files not separated by commas, when the first lines use it)"
                unreadable[name] = (
                    f"{path}: column {name!r}, line {body[i][0]}: {r[j]!r} is not a number{hint}; every cell must be a "
                    f"number or a missing value (empty, NaN, NA, N/A, null)"
                )
                vals[i:] = np.nan  # never read (Table.column raises), but not left uninitialised
                break
        cols[name] = vals
    lines = np.asarray([n for n, _ in body], dtype=np.int64)
    return cols, lines, {"delimiter": DELIMITER_NAMES[d], "decimal": "," if comma else "."}, unreadable
