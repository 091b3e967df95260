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
  :data:`MAX_LINE_CHARS` is an error (the file is read a block at a time: memory stays bounded).
* **Clock**: a column named like a time (``t``, ``time``, ``timestamp``, with an
  optional unit suffix ``_s``, ``_ms``, ``_us``, ``_ns``; seconds without one), whose
  values are all numbers and strictly increasing, gives the samples' times.

Reading
-------
The header and the first lines are read here (detection); the rows by Apache Arrow's CSV reader
(:func:`streamid.logs.arrow_tables.stream_csv`: hundreds of MB/s), only the columns asked for (and the
time-like ones), a block at a time straight into float64 arrays.  A file it refuses (a ragged row, text in
a column read, a row longer than a block, undecodable bytes, odd blanks) is read again here line by line,
which names the row and column at fault or reads what Arrow would not; both give the same numbers.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

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
    "RowLines",
    "time_unit_ns",
    "clock_of",
    "CsvLayout",
    "csv_layout",
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
    """The first time-like column whose values are all numbers and strictly increasing, as integer ns.

    Made a block of rows at a time: beside the columns it holds the times and one byte a row, never a float copy.
    """
    for name, v in columns.items():
        unit = time_unit_ns(name)
        if unit is None or v.size < 2 or not (np.isfinite(v[0]) and np.isfinite(v[-1])):
            continue
        if not np.all(v[1:] > v[:-1]):  # strictly increasing between finite ends: every value a finite number
            continue
        if not max(abs(float(v[0])), abs(float(v[-1]))) * unit < 9e18:  # beyond int64 ns (~292 years): not a clock
            continue
        t_ns = np.empty(v.size, dtype=np.int64)
        for a in range(0, v.size, 1 << 16):
            t_ns[a : a + (1 << 16)] = np.round(v[a : a + (1 << 16)] * float(unit))
        if np.all(t_ns[1:] > t_ns[:-1]):
            return name, t_ns
    return None


def _encoding(head: bytes) -> str:
    if head.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "utf-32"
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "utf-16"
    return "utf-8-sig"


def _file_encoding(path: Path) -> str:
    try:
        with open(path, "rb") as fb:
            head = fb.read(64)
    except OSError as exc:
        raise DataError(f"cannot read CSV file {path}: {exc}") from None
    enc = _encoding(head)
    if enc == "utf-8-sig" and b"\x00" in head:
        raise DataError(f"{path}: holds NUL bytes, which no text CSV has (UTF-16 without a byte-order mark?): "
                        "save it as UTF-8 (UTF-16 or UTF-32 with a byte-order mark are read too)")
    return enc


def _numbered_lines(path: Path, enc: str) -> Iterator[tuple[int, str, bool]]:
    """Every line of the file with its 1-based number, and whether it ends where Arrow's reader sees a line end too
    (LF, CR, CR LF; not a form feed or a Unicode line separator, which :meth:`str.splitlines` also
    splits at). Read a line at a time, none longer than :data:`MAX_LINE_CHARS`."""
    n = 0
    try:
        with open(path, newline="", encoding=enc) as fh:
            while ln := fh.readline(MAX_LINE_CHARS + 1):
                if len(ln) > MAX_LINE_CHARS:
                    raise DataError(f"{path}: line {n + 1} is longer than {MAX_LINE_CHARS} characters; a CSV "
                                    "row holds one sample of every column (is this a CSV file?)")
                parts = ln.splitlines()
                for k, part in enumerate(parts):
                    n += 1
                    yield n, part, len(parts) == 1 or k == len(parts) - 1
    except OSError as exc:
        raise DataError(f"cannot read CSV file {path}: {exc}") from None
    except UnicodeDecodeError as exc:
        bad = exc.object[exc.start : exc.start + 1].hex()
        raise DataError(
            f"{path}: is not {'UTF-8' if enc == 'utf-8-sig' else enc.upper()} text (byte 0x{bad} cannot be decoded): "
            "save it as UTF-8 (UTF-16 or UTF-32 with a byte-order mark are read too)"
        ) from None


def _line_breaks(path: Path) -> int:
    """An upper bound of the file's lines (its line-end bytes + 1): the rows an array is made for."""
    n, buf = 1, bytearray(1 << 20)
    with open(path, "rb") as fb:
        while k := fb.readinto(buf):
            view = buf if k == len(buf) else buf[:k]
            n += view.count(b"\n") + view.count(b"\r")
    return n


class RowLines:
    """The 1-based file line of every data row (``lines[i]``), found by reading the file again when first asked
    (only a message naming a row asks): blank lines are not rows, so rows and lines drift apart at each."""

    def __init__(self, path: Path, enc: str, header_line: int, rows: int) -> None:
        self._path, self._enc, self._header, self._rows = path, enc, header_line, rows
        self._starts: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None

    def __len__(self) -> int:
        return self._rows

    def _scan(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        rows, lines, i, last = [], [], 0, -1
        for n, ln, _ in _numbered_lines(self._path, self._enc):
            if n <= self._header or not ln.strip():
                continue
            if n != last + 1:
                rows.append(i)
                lines.append(n)
            i, last = i + 1, n
        return np.asarray(rows, dtype=np.int64), np.asarray(lines, dtype=np.int64)

    def __getitem__(self, i: int) -> int:
        if self._starts is None:
            self._starts = self._scan()
        rows, lines = self._starts
        j = int(np.searchsorted(rows, i, side="right")) - 1
        return int(lines[j] + (int(i) - rows[j]))


class _Normalised(io.RawIOBase):
    """A CSV as UTF-8 bytes for Arrow's reader: decoded from UTF-16/32, and for a whitespace-separated file every
    run of blanks made one tab (a line's leading and trailing blanks dropped), as :meth:`str.split` reads it."""

    _EDGES = re.compile(r"[^\S\r\n]*(\r\n|\r|\n)[^\S\r\n]*")
    _RUNS = re.compile(r"[^\S\r\n]+")

    def __init__(self, path: Path, enc: str, whitespace: bool) -> None:
        super().__init__()
        self._fh = open(path, newline="", encoding=enc)  # noqa: SIM115 - closed by close()
        self._ws, self._carry, self._buf, self._eof, self._start = whitespace, "", b"", False, True

    def readable(self) -> bool:
        return True

    def _more(self) -> None:
        text = self._fh.read(1 << 20)
        if not text:
            self._eof, text, self._carry = True, self._carry, ""
        else:
            text = self._carry + text
            cut = max(text.rfind("\n"), text.rfind("\r")) + 1
            if cut == 0 and len(text) <= 4 * MAX_LINE_CHARS:
                self._carry = text
                return
            text, self._carry = (text[:cut], text[cut:]) if cut else (text, "")
        if self._ws:
            text = self._RUNS.sub("\t", self._EDGES.sub("\n", text))
            if self._start or text.startswith("\t"):
                text = text.removeprefix("\t")
            text = text.removesuffix("\t")
        self._start = False
        self._buf += text.encode("utf-8")

    def read(self, size: int | None = -1) -> bytes:
        while not self._eof and (size is None or size < 0 or len(self._buf) < size):
            self._more()
        k = len(self._buf) if size is None or size < 0 else size
        out, self._buf = self._buf[:k], self._buf[k:]
        return out

    def close(self) -> None:
        self._fh.close()
        super().close()


def _python_read(path: Path, enc: str, header_line: int, header: list[str], d: str, comma: bool,
                 wanted: list[str], n_max: int) -> tuple[dict[str, NDArray[np.float64]], dict[str, str]]:
    """The rows read line by line: the first ragged row, long line or undecodable byte stops the file with an error
    naming it; a wanted column's first cell that is neither a number nor a missing value makes it unreadable."""
    out = {c: np.empty(n_max) for c in wanted}
    where = [(c, header.index(c)) for c in wanted]
    unreadable: dict[str, str] = {}
    k = 0
    for line_no, ln, _ in _numbered_lines(path, enc):
        if line_no <= header_line or not ln.strip():
            continue
        r = _split(ln, d)
        if len(r) != len(header):
            raise DataError(
                f"{path}: line {line_no} has {len(r)} fields; the header has {len(header)} "
                f"(delimiter {DELIMITER_NAMES[d]}): {ln[:80]!r}"
            )
        for name, j in where:
            cell = r[j].strip()
            if cell.lower() in MISSING_TOKENS:
                out[name][k] = np.nan
                continue
            try:
                out[name][k] = float(cell.replace(",", ".") if comma else cell)
            except ValueError:
                if name in unreadable:
                    continue
                hint = ""
                if "," in cell and not comma:
                    hint = " (a decimal comma? it is read only in files not separated by commas, when the first lines use it)"
                unreadable[name] = (
                    f"{path}: column {name!r}, line {line_no}: {r[j]!r} is not a number{hint}; every cell must be a "
                    f"number or a missing value (empty, NaN, NA, N/A, null)"
                )
        k += 1
    for name, v in out.items():
        v.resize(k, refcheck=False)
        if name in unreadable:
            v[:] = np.nan  # never read (Table.column raises), but not left uninitialised
    return out, unreadable


Progress = Callable[[float, float], Any]


@dataclass(frozen=True)
class CsvLayout:
    """How a CSV is laid out, judged on its header and first lines (the module's rules)."""

    enc: str
    header_no: int  # the header's 1-based file line
    header: list[str]
    delimiter: str
    comma: bool  # decimal comma
    wanted: list[str]  # the columns read: those asked for and the time-like ones, in the header's order
    plain: bool  # every line ends where Arrow's reader sees a line end

    def source(self, path: Path) -> Any:
        """What Arrow's reader reads: the path, or the text normalised (:class:`_Normalised`; close it)."""
        return str(path) if self.enc == "utf-8-sig" and self.delimiter != " " else _Normalised(
            path, self.enc, self.delimiter == " ")

    def arrow_options(self) -> dict[str, Any]:
        """:func:`streamid.logs.arrow_tables.stream_csv`'s delimiter, decimal and quoting."""
        d = self.delimiter
        return {"delimiter": "\t" if d == " " else d, "decimal": "," if self.comma else ".", "quoting": d != " "}


def csv_layout(path: Path, delimiter: str | None = None, columns: Sequence[str] | None = None) -> CsvLayout:
    """The layout of the CSV at ``path`` (:func:`read_delimited`'s first step; a reader a piece at a time's too).

    Raises
    ------
    DataError
        Unreadable file, no header or data, duplicate names, an undetectable delimiter.
    """
    enc = _file_encoding(path)
    head: list[tuple[int, str]] = []
    plain = True  # every line ends where Arrow's reader sees a line end
    for n, ln, same in _numbered_lines(path, enc):
        plain = plain and same
        if ln.strip():
            head.append((n, ln))
            if len(head) > SNIFF_LINES:
                break
    if len(head) < 2:
        raise DataError(f"{path}: a CSV file needs a header row with column names and at least one data row")
    header_no, header_line = head[0][0], head[0][1].lstrip()
    if header_line.startswith("#"):
        header_line = header_line[1:]
    body = [ln for _, ln in head[1:]]
    d = detect_delimiter(header_line, body, str(path)) if delimiter is None else delimiter
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
    comma = d != "," and _decimal_comma([_split(ln, d) for ln in body])
    asked = set(header if columns is None else columns)
    wanted = [c for c in header if c in asked or time_unit_ns(c) is not None]
    return CsvLayout(enc, header_no, header, d, comma, wanted, plain)


def read_delimited(
    path: Path, delimiter: str | None = None, columns: Sequence[str] | None = None, progress: Progress | None = None,
) -> tuple[dict[str, NDArray[np.float64]], RowLines, dict[str, Any], dict[str, str]]:
    """Columns (NaN where a cell is missing), the 1-based file line of every row, how the file was read, and why
    each unreadable column cannot be used.

    Parameters
    ----------
    columns : optional
        The columns to read (names not in the header are left out; the time-like ones are read too, for the
        clock); default every column.
    progress : optional
        Called as ``progress(rows_read, rows_at_most)`` as the rows are read.

    Returns
    -------
    columns, lines, how, unreadable
        ``how`` holds ``delimiter`` (its name), ``decimal`` (``"."`` or ``","``) and ``columns`` (every name of
        the header). ``unreadable`` maps a column holding a cell that is neither a number nor a missing value to
        the error naming its first such cell: it is raised only if the column is used (a notes column beside the
        signals does not stop a file).

    Raises
    ------
    DataError
        Unreadable file, no header or data, duplicate names, a row with another number of
        fields than the header.
    """
    lay = csv_layout(path, delimiter, columns)
    enc, header_no, header, d, comma, wanted, plain = (lay.enc, lay.header_no, lay.header, lay.delimiter, lay.comma,
                                                        lay.wanted, lay.plain)
    n_max = _line_breaks(path)
    cols: dict[str, NDArray[np.float64]] | None = None
    unreadable: dict[str, str] = {}
    if not wanted:
        cols = {}
    elif plain:
        from streamid.logs.arrow_tables import Refused, stream_csv

        source: Any = lay.source(path)
        try:
            cols = stream_csv(source, header, header_no, wanted, n_max=n_max, progress=progress, **lay.arrow_options())
        except Refused:
            cols = None
        finally:
            if not isinstance(source, str):
                source.close()
    if cols is None:  # refused by Arrow: read here, to name the fault (or read what Arrow would not)
        cols, unreadable = _python_read(path, enc, header_no, header, d, comma, wanted, n_max)
    rows = len(next(iter(cols.values()))) if cols else 0
    if progress is not None:
        progress(rows, rows)
    how = {"delimiter": DELIMITER_NAMES[d], "decimal": "," if comma else ".", "columns": header}
    return cols, RowLines(path, enc, header_no, rows), how, unreadable
