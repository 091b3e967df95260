"""The one module that imports pyarrow: CSV text, Parquet and Arrow IPC (Feather) files read into float64 columns.

pyarrow (Apache Arrow's C++ readers; installed with rerun-sdk already) parses CSV at hundreds of MB/s and
reads Parquet and Arrow IPC files column by column.  Only the columns asked for are converted, a block at a
time, straight into preallocated float64 numpy arrays: a read holds the columns once plus a few blocks
(~1 MiB each), never a table beside its copy.  Missing cells (CSV null tokens, Parquet / Arrow nulls)
become NaN.  Callers import this module lazily (``streamid --help`` does not load pyarrow).

:func:`stream_csv` is the fast path of :mod:`streamid.logs.csv_table`: it raises :class:`Refused` on anything
that is not a clean file of numbers (a ragged row, text in a column read, a row longer than a block), and
that module then reads the file in Python to name the row and column at fault, with its own wording.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from numpy.typing import NDArray

from streamid.errors import DataError

__all__ = ["BLOCK_BYTES", "Refused", "csv_batches", "float_pieces", "open_columnar", "stream_csv", "read_columnar",
           "write_float_columns"]

#: Bytes of CSV text parsed at a time; a row must fit in one (csv_table.MAX_LINE_CHARS is the same 1 MiB).
BLOCK_BYTES = 1 << 20

Progress = Callable[[float, float], Any]


class Refused(Exception):
    """The columnar reader could not read the file as clean numbers (the caller finds and names the fault)."""


def _case_variants(word: str) -> list[str]:
    out = [""]
    for ch in word:
        out = [p + c for p in out for c in {ch.lower(), ch.upper()}]
    return out


#: Cells read as missing (csv_table.MISSING_TOKENS in any case; "nan" is parsed as NaN by Arrow itself).
NULL_TOKENS = sorted({"", *(v for w in ("na", "n/a", "null", "none", "nan") for v in _case_variants(w))})


def _into(out: NDArray[np.float64], arr: Any) -> None:
    """Copy one Arrow array (any numeric type, nulls) into ``out`` (its length) as float64, nulls as NaN."""
    if not pa.types.is_float64(arr.type):
        arr = arr.cast(pa.float64(), safe=False)
    n = len(arr)
    valid, data = arr.buffers()[:2]
    if data is not None and n:
        out[:] = np.frombuffer(data, dtype=np.float64, count=n, offset=arr.offset * 8)
    if arr.null_count:
        bits = np.unpackbits(np.frombuffer(valid, dtype=np.uint8), bitorder="little", count=arr.offset + n)[arr.offset:]
        out[bits == 0] = np.nan


def _fill(batches: Iterable[Any], names: Sequence[str], n_max: int, progress: Progress | None,
          total: float) -> dict[str, NDArray[np.float64]]:
    """Record batches holding ``names`` copied into one float64 array per name (``n_max`` rows at most)."""
    out = {c: np.empty(n_max, dtype=np.float64) for c in names}
    k = 0
    for b in batches:
        m = b.num_rows
        if k + m > n_max:
            raise Refused(f"more rows than the {n_max} counted")
        for c in names:
            _into(out[c][k:k + m], b.column(c))
        k += m
        if progress is not None:
            progress(k, total)
    for v in out.values():
        v.resize(k, refcheck=False)  # shrinks in place (the pages past k were never touched)
    return out


def stream_csv(source: str | BinaryIO, names: Sequence[str], skip_lines: int, wanted: Sequence[str], *,
               delimiter: str, decimal: str, quoting: bool, n_max: int,
               progress: Progress | None = None) -> dict[str, NDArray[np.float64]]:
    """The ``wanted`` columns of a CSV whose header (``names``) is on line ``skip_lines``, as float64.

    Raises
    ------
    Refused
        A row with another number of fields, a cell in a wanted column that is neither a number nor a
        missing token, a row longer than :data:`BLOCK_BYTES`, undecodable text.
    """
    try:
        return _fill(csv_batches(source, names, skip_lines, wanted, delimiter=delimiter, decimal=decimal,
                                 quoting=quoting), wanted, n_max, progress, n_max)
    except (pa.ArrowException, UnicodeDecodeError, ValueError) as exc:
        raise Refused(str(exc)) from None


def csv_batches(source: str | BinaryIO, names: Sequence[str], skip_lines: int, wanted: Sequence[str], *,
                delimiter: str, decimal: str, quoting: bool) -> Iterator[Any]:
    """Arrow's streaming CSV reader over ``source`` (:func:`stream_csv`'s settings): record batches of the
    ``wanted`` columns as float64, a block (:data:`BLOCK_BYTES`) at a time."""
    read = pacsv.ReadOptions(column_names=list(names), skip_rows=skip_lines, block_size=BLOCK_BYTES, use_threads=True)
    parse = pacsv.ParseOptions(delimiter=delimiter, quote_char='"' if quoting else False)
    convert = pacsv.ConvertOptions(column_types={c: pa.float64() for c in wanted}, include_columns=list(wanted),
                                   null_values=NULL_TOKENS, strings_can_be_null=True, decimal_point=decimal)
    yield from pacsv.open_csv(source, read_options=read, parse_options=parse, convert_options=convert)


def float_pieces(batches: Iterable[Any], names: Sequence[str],
                 ns: Sequence[str] = ()) -> Iterator[tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.int64]]]]:
    """Record batches as float64 arrays of ``names`` (nulls as NaN, as :func:`_fill` reads them) and integer ns of
    the timestamp or duration columns ``ns``, a batch at a time.

    Raises
    ------
    Refused
        A batch Arrow cannot read (a ragged row, text in a column read...) or a null time.
    """
    try:
        for b in batches:
            out = {}
            for c in names:
                out[c] = np.empty(b.num_rows)
                _into(out[c], b.column(c))
            times = {}
            for c in ns:
                t = _ns([b], c, _ns_unit(b.schema.field(c).type), b.num_rows)
                if t is None:
                    raise Refused(f"a null time in {c!r}")
                times[c] = t
            yield out, times
    except (pa.ArrowException, UnicodeDecodeError, ValueError) as exc:
        raise Refused(str(exc)) from None


def _ns_unit(t: Any) -> Any:
    return pa.timestamp("ns", t.tz) if pa.types.is_timestamp(t) else pa.duration("ns")


def _numeric(t: Any) -> bool:
    return bool(pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t)
                or pa.types.is_decimal(t) or pa.types.is_null(t))


def _ns(batches: Iterable[Any], name: str, unit: Any, rows: int) -> NDArray[np.int64] | None:
    """A timestamp or duration column as integer ns (None if it has a null)."""
    out, k = np.empty(rows, dtype=np.int64), 0
    for b in batches:
        arr = b.column(name)
        if arr.null_count:
            return None
        v = arr.cast(unit).cast(pa.int64())
        out[k:k + len(v)] = np.frombuffer(v.buffers()[1], dtype=np.int64, count=len(v), offset=v.offset * 8)
        k += len(v)
    return out[:k]


def open_columnar(path: str, kind: str) -> tuple[list[str], dict[str, Any], dict[str, str], int,
                                                Callable[[list[str]], Iterable[Any]]]:
    """A Parquet or Arrow IPC file opened (:func:`read_columnar`'s ``kind``): every column's name, the timestamp
    and duration columns' types, why each column that is not numeric cannot be a signal, the rows, and
    ``batches(columns)``: its record batches of those columns (~65,536 rows each for Parquet, the file's own for
    IPC). Raises Arrow's or the system's error."""
    if kind == "parquet":
        import pyarrow.parquet as pq

        pf = pq.ParquetFile(path, pre_buffer=False)  # row groups not read ahead whole: ~35 MB less at 10 M rows
        schema, rows = pf.schema_arrow, int(pf.metadata.num_rows)

        def batches(cols: list[str]) -> Iterable[Any]:
            return pf.iter_batches(batch_size=1 << 16, columns=cols)
    else:
        try:
            ipc = pa.ipc.open_file(pa.OSFile(path))
            schema, rows = ipc.schema, int(ipc.count_rows())

            def batches(cols: list[str]) -> Iterable[Any]:
                return (ipc.get_batch(i).select(cols) for i in range(ipc.num_record_batches))
        except pa.ArrowInvalid:  # the IPC stream format (no footer): rows counted in a first pass
            stream = pa.ipc.open_stream(pa.OSFile(path))
            schema, rows = stream.schema, sum(b.num_rows for b in stream)

            def batches(cols: list[str]) -> Iterable[Any]:
                return (b.select(cols) for b in pa.ipc.open_stream(pa.OSFile(path)))
    names = list(schema.names)
    if len(set(names)) != len(names):
        raise DataError(f"{path}: the column names must be distinct; got {names}")
    temporal = {f.name: f.type for f in schema if pa.types.is_timestamp(f.type) or pa.types.is_duration(f.type)}
    unreadable = {f.name: (f"{path}: column {f.name!r} holds {f.type} values, not numbers; only numeric "
                           "columns (integer, float, boolean, decimal) are signals"
                           + (" (a timestamp or duration column gives the clock)" if f.name in temporal else ""))
                  for f in schema if not _numeric(f.type)}
    return names, temporal, unreadable, rows, batches


def read_columnar(path: str, kind: str, keep: Callable[[str], bool] | None = None, progress: Progress | None = None
                  ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.int64]], list[str], dict[str, str]]:
    """A Parquet (``kind="parquet"``) or Arrow IPC (``"ipc"``: Feather v2, file or stream format) file's columns.

    Returns
    -------
    columns, times, names, unreadable
        float64 columns of the numeric columns ``keep`` accepts (every one when None); timestamp and duration
        columns ``keep`` accepts as integer ns (clock candidates); every column name of the file; why each
        other column cannot be used as a signal.
    """
    try:
        names, temporal, unreadable, rows, batches = open_columnar(path, kind)
        take = [c for c in names if c not in unreadable and (keep is None or keep(c))]
        times: dict[str, NDArray[np.int64]] = {}
        for c, t in temporal.items():
            if keep is None or keep(c):
                ns = _ns(batches([c]), c, _ns_unit(t), rows)
                if ns is not None:
                    times[c] = ns
        try:
            return _fill(batches(take), take, rows, progress, rows), times, names, unreadable
        finally:  # the pool keeps the batches' freed pages (~45 MB at 1,000,000 rows): back to the system
            pa.default_memory_pool().release_unused()
    except (pa.ArrowException, OSError, Refused) as exc:
        what = "Parquet" if kind == "parquet" else "Arrow IPC (Feather)"
        text = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise DataError(f"{path}: not a readable {what} file: {text} (a cut or damaged file is not read)") from None


def write_float_columns(path: str, blocks: Iterable[dict[str, NDArray[np.float64]]], kind: str) -> None:
    """Write float64 column blocks as a CSV without header rows (``kind="csv"``, appended) or one Parquet file
    (``"parquet"``, a row group a block): the test and benchmark files of the readers above."""
    if kind == "csv":
        with open(path, "ab") as fh:
            for b in blocks:
                pacsv.write_csv(pa.table(b), fh, pacsv.WriteOptions(include_header=False))
        return
    import pyarrow.parquet as pq

    writer = None
    try:
        for b in blocks:
            t = pa.table(b)
            writer = writer or pq.ParquetWriter(path, t.schema)
            writer.write_table(t)
    finally:
        if writer is not None:
            writer.close()
