"""Load identification data from CSV (header row), MATLAB ``.mat``, streamid MCAP logs, MDF files or ROS 2 bags.

:func:`load_table` reads every numeric column of a file into ``{name: array}``;
:func:`load_record` picks the input and output columns by name and checks them;
:func:`load_dataset` splits them into an estimation part (the first samples) and a
validation part (the rest), or takes the validation part from a second file.

Formats
-------
* ``.csv`` (also ``.tsv``, or any extension with ``fmt="csv"``): first
  row = column names, then one row per sample; the delimiter (``,`` ``;`` tab ``|``
  whitespace) and a decimal comma are detected, empty / NaN / NA cells are missing
  values, and a strictly increasing column named like a time (``time_s``, ``t_ms``...)
  gives the samples' times: :mod:`streamid.logs.csv_table`.
* ``.mat`` (MATLAB v4-v7.2, read with :func:`scipy.io.loadmat`): every numeric
  vector variable is a column (``N x 1`` or ``1 x N``); a matrix ``X`` of shape
  ``N x k`` gives columns ``X[0] .. X[k-1]``, bounded before loading (:mod:`streamid.logs.mat_files`); MATLAB
  v7.3 (HDF5) files: :mod:`streamid.logs.mat73_file`.
* ``.mcap``: a streamid log (see :mod:`streamid.logs.mcap_files`); columns are the
  stream's input and output channel names.
* ``.parquet`` (``.pq``) and Arrow IPC / Feather v2 (``.feather``, ``.arrow``, ``.ipc``): every numeric column
  (integer, float, boolean, decimal; nulls are missing values), a time-like name giving the clock as in a
  CSV: :mod:`streamid.logs.arrow_tables`.

CSV, Parquet and Arrow files are read by Apache Arrow (pyarrow), only the columns named (and the time-like
ones) when the caller names them, straight into float64 arrays.
* ``.mf4``/``.mdf`` (ASAM MDF: :mod:`streamid.logs.mdf_file`) and ROS 2 bags (a bag directory, its ``.db3``, or an
  ``.mcap`` whose profile is ``ros2``: :mod:`streamid.logs.ros2_bag`): signals recorded at their own times, read
  by name (``signals``: the inputs, then the output) and put on the output's own timestamps
  (:mod:`streamid.logs.timed`).

The chosen columns are checked (an input equal to the output, a time column as an
input...) and missing values handled as :mod:`streamid.logs.columns` says.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.logs.table import Table
from streamid.errors import DataError
from streamid.logs.columns import MISSING_POLICIES, check_columns, handle_missing
from streamid.logs.csv_table import clock_of, read_delimited, time_unit_ns

__all__ = ["PERIOD_TOLERANCE", "Table", "Dataset", "Record", "load_table", "load_record", "load_dataset", "same_period",
           "split_index"]


@dataclass(frozen=True)
class Dataset:
    """Inputs and output split into estimation and validation parts."""

    path: str
    input_names: tuple[str, ...]
    output_name: str
    u_est: NDArray[np.float64]
    y_est: NDArray[np.float64]
    u_val: NDArray[np.float64]
    y_val: NDArray[np.float64]
    n_est: int
    t_ns: NDArray[np.int64] | None = None
    #: warnings about the data (missing values dropped or filled, a time column used as an input...)
    notes: tuple[str, ...] = ()
    #: how the file was read: ``delimiter``, ``decimal``, ``clock`` column, ``missing`` (policy and counts)
    info: dict[str, Any] = field(default_factory=dict)
    #: sample period of the file's clock (None when it has none)
    period_ns: int | None = None
    #: the validation data's own file (None: the validation data are the data file's last samples)
    validation_path: str | None = None

    @property
    def n_val(self) -> int:
        return int(self.y_val.shape[0])

    def window(self) -> dict[str, Any]:
        """Description of the estimation window (recorded in the model)."""
        w: dict[str, Any] = {"source": os.path.basename(self.path), "start": 0, "stop": self.n_est, "n_samples": self.n_est}
        if self.t_ns is not None and self.n_est:
            w["t0_ns"] = int(self.t_ns[0])
            w["t1_ns"] = int(self.t_ns[self.n_est - 1])
        if self.period_ns:
            w["period_ns"] = int(self.period_ns)
        return w


Progress = Callable[[float, float], Any]


def _read_csv(path: Path, delimiter: str | None = None, columns: Sequence[str] | None = None,
              progress: Progress | None = None) -> Table:
    cols, lines, how, unreadable = read_delimited(path, delimiter, columns, progress)
    for name, why in unreadable.items():
        if time_unit_ns(name) is not None:  # a clock column, used whenever it is one: its fault stops the file
            raise DataError(why)
    clock = clock_of(cols)
    t_ns = period_ns = None
    if clock is not None:
        how["clock"] = clock[0]
        t_ns = clock[1]
        period_ns = int(np.median(np.diff(t_ns), overwrite_input=True))
    return Table(str(path), cols, t_ns=t_ns, period_ns=period_ns, meta={"lines": lines, **how}, unreadable=unreadable)


def _read_columnar(path: Path, kind: str, columns: Sequence[str] | None, progress: Progress | None) -> Table:
    from streamid.logs.arrow_tables import read_columnar

    asked = None if columns is None else set(columns)
    cols, times, names, unreadable = read_columnar(
        str(path), kind, None if asked is None else (lambda c: c in asked or time_unit_ns(c) is not None), progress)
    clock = clock_of(cols)
    if clock is None:  # a timestamp or duration column, strictly increasing
        clock = next(((c, t) for c, t in times.items() if t.size > 1 and np.all(t[1:] > t[:-1])), None)
    meta: dict[str, Any] = {"columns": names, "format": kind}
    t_ns = period_ns = None
    if clock is not None:
        meta["clock"], t_ns = clock
        period_ns = int(np.median(np.diff(t_ns), overwrite_input=True))
    return Table(str(path), cols, t_ns=t_ns, period_ns=period_ns, meta=meta, unreadable=unreadable)


def _read_mat(path: Path) -> Table:
    with open(path, "rb") as f:  # MATLAB v7.3 is HDF5 behind a 128-byte text header that says so
        v73 = b"MATLAB 7.3" in f.read(128)
    if v73:
        from streamid.logs.mat73_file import read_mat73_table

        return read_mat73_table(path)
    from streamid.logs.mat_files import read_mat_columns

    cols = read_mat_columns(path)
    return Table(str(path), cols, meta={"lengths": {k: len(v) for k, v in cols.items()}})


def _read_mcap(path: Path, stream: str | None) -> Table:
    from streamid.logs.arrays import read_log_arrays

    arr = read_log_arrays(path, stream)
    cols = {**{k: np.asarray(v, dtype=np.float64) for k, v in arr.inputs.items()}}
    for k, v in arr.outputs.items():
        if k in cols:
            raise DataError(f"{path}: channel name {k!r} is both an input and an output of stream {arr.stream!r}")
        cols[k] = np.asarray(v, dtype=np.float64)
    meta = {"stream": arr.stream, "inputs": list(arr.inputs), "outputs": list(arr.outputs), "metadata": arr.metadata}
    return Table(str(path), cols, t_ns=np.asarray(arr.t_ns, dtype=np.int64), period_ns=int(arr.period_ns), meta=meta)


#: Extensions read by Apache Arrow's Parquet and IPC readers (Feather v2 is the IPC file format).
COLUMNAR_KINDS = {"parquet": "parquet", "pq": "parquet", "feather": "ipc", "arrow": "ipc", "ipc": "ipc"}


def load_table(
    path: str | os.PathLike[str], *, stream: str | None = None, fmt: str | None = None, delimiter: str | None = None,
    columns: Sequence[str] | None = None, progress: Progress | None = None, signals: Sequence[str] | None = None,
) -> Table:
    """Read a data file's numeric columns.

    Parameters
    ----------
    path : path-like
        ``.csv``, ``.parquet``, ``.feather``/``.arrow``/``.ipc``, ``.mat`` or ``.mcap`` file.
    stream : str, optional
        Stream of an MCAP log holding several.
    fmt : {"csv", "parquet", "feather", "mat", "mcap"}, optional
        Format, if the extension does not tell.
    delimiter : str, optional
        CSV delimiter (``,`` ``;`` ``\\t`` ``|`` or ``" "`` for whitespace); default detected.
    columns : optional
        Of a CSV, Parquet or Arrow file, read only these columns (and the time-like ones, for the clock);
        ``meta["columns"]`` names every column. Default: every column.
    progress : optional
        Called as ``progress(rows_read, rows_at_most)`` while a CSV, Parquet or Arrow file is read.
    signals : sequence of str, optional
        The signals of an MDF file or ROS 2 bag to read (the inputs, then the output, whose timestamps are the
        grid); the other formats read every column and ignore it.

    Raises
    ------
    DataError
        Unreadable file, non-numeric CSV field, unknown format.
    LogError
        An MCAP log that cannot be read.
    """
    p = Path(path)
    if not p.is_file() and not (p / "metadata.yaml").is_file():
        raise DataError(f"data file {str(path)!r} does not exist (or is not a file, nor a ROS 2 bag directory)")
    kind = (fmt or p.suffix.lstrip(".")).lower()
    if kind in ("mf4", "mdf"):
        from streamid.logs.mdf_file import read_mdf_table
        return read_mdf_table(p, signals)
    if kind == "db3" or p.is_dir() or (kind == "mcap" and _is_ros2_mcap(p)):
        from streamid.logs.ros2_bag import read_bag_table
        return read_bag_table(p, signals)
    if kind in ("csv", "tsv"):
        return _read_csv(p, delimiter, columns, progress)
    if kind in COLUMNAR_KINDS:
        return _read_columnar(p, COLUMNAR_KINDS[kind], columns, progress)
    if kind == "mat":
        return _read_mat(p)
    if kind == "mcap":
        return _read_mcap(p, stream)
    raise DataError(f"{path}: unknown data format {kind!r}; accepted: .csv/.tsv (header row), "
                    ".parquet, .feather/.arrow/.ipc, .mat, .mcap, .mf4/.mdf, a ROS 2 bag (directory, .mcap or .db3)")


def _is_ros2_mcap(p: Path) -> bool:
    from streamid.logs.ros2_bag import is_ros2_mcap

    return is_ros2_mcap(p)


def split_index(n: int, est: int | None = None, est_fraction: float | None = None) -> int:
    """Number of estimation samples: ``est``, or ``round(est_fraction * n)``, default half."""
    if est is not None and est_fraction is not None:
        raise DataError("give either the number of estimation samples or the fraction, not both")
    if est is not None:
        if not (isinstance(est, int) and 1 <= est < n):
            raise DataError(f"the number of estimation samples must be an integer in [1, {n - 1}] for {n} samples; got {est!r}")
        return est
    f = 0.5 if est_fraction is None else est_fraction
    if not (0.0 < f < 1.0):
        raise DataError(f"the estimation fraction must be in (0, 1); got {f!r}")
    k = int(round(f * n))
    if not 1 <= k < n:
        raise DataError(f"an estimation fraction of {f} leaves no estimation or no validation sample of {n}")
    return k


@dataclass(frozen=True)
class Record:
    """The chosen columns of one data file (one experiment), checked, missing values handled."""

    path: str
    input_names: tuple[str, ...]
    output_name: str
    u: NDArray[np.float64]  # (N, n_inputs)
    y: NDArray[np.float64]  # (N,)
    t_ns: NDArray[np.int64] | None = None
    notes: tuple[str, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)
    period_ns: int | None = None


def load_record(
    path: str | os.PathLike[str],
    inputs: list[str] | tuple[str, ...],
    output: str,
    *,
    stream: str | None = None,
    delimiter: str | None = None,
    missing: str = "error",
    allow_time_input: bool = False,
    progress: Progress | None = None,
) -> Record:
    """Load the named columns of one file and check them, handling missing values (see :func:`load_dataset`);
    ``progress(rows_read, rows_at_most)`` as a CSV, Parquet or Arrow file is read."""
    if not inputs:
        raise DataError("at least one input column is needed (--input COL)")
    if missing not in MISSING_POLICIES:
        raise DataError(f"missing must be one of {MISSING_POLICIES}; got {missing!r}")
    names = list(dict.fromkeys([*inputs, output]))
    table = load_table(path, stream=stream, delimiter=delimiter, columns=names, progress=progress,
                       signals=[*inputs, output])
    cols = {c: table.column(c) for c in names}
    lengths = {c: len(a) for c, a in cols.items()}
    if len(set(lengths.values())) != 1:
        raise DataError(f"{path}: the columns have different lengths {lengths}; all must be equal")
    notes = list(table.meta.get("notes", ())) + check_columns(str(path), list(inputs), output, cols,
                                                              allow_time_input=allow_time_input)
    lines = table.meta.get("lines")
    clean = handle_missing(str(path), cols, missing, lines)
    notes += clean.notes
    info: dict[str, Any] = {k_: v for k_, v in table.meta.items() if k_ in ("delimiter", "decimal", "clock")}
    info["rows"] = len(table)
    info["missing"] = {
        "policy": missing,
        "rows_with_missing": clean.rows_missing,
        "rows_dropped": clean.dropped,
        "values_filled": clean.filled,
        "places_spacing_broken": clean.gaps,
    }
    return Record(
        str(path), tuple(inputs), output, np.column_stack([clean.columns[c] for c in inputs]), clean.columns[output],
        table.t_ns[clean.keep] if table.t_ns is not None else None, tuple(notes), info, table.period_ns,
    )


#: Relative difference of two sample periods taken as one period (clocks of two files, of a model and a file).
PERIOD_TOLERANCE = 1e-3


def same_period(a_ns: int, b_ns: int) -> bool:
    """Whether two sample periods are one, within :data:`PERIOD_TOLERANCE` (a NARX model's lags count samples)."""
    return abs(a_ns - b_ns) <= PERIOD_TOLERANCE * max(a_ns, b_ns)


def _same_period(est: Record, val: Record) -> None:
    """Refuse a validation file sampled at another rate than the estimation file (when both have clocks)."""
    a, b = est.period_ns, val.period_ns
    if a and b and not same_period(a, b):
        raise DataError(
            f"the validation file {val.path} samples every {b / 1e6:.6g} ms but {est.path} every {a / 1e6:.6g} ms: "
            f"a NARX model's lags count samples, so both must have one sample period (resample one of them)"
        )


def _joined_times(est: Record, val: Record) -> NDArray[np.int64] | None:
    """Times for the estimation samples then the validation file's, drawn after them (one axis for both)."""
    period = est.period_ns or val.period_ns
    if not period or (est.t_ns is None and val.t_ns is None):
        return None
    t_est = est.t_ns if est.t_ns is not None else np.arange(len(est.y), dtype=np.int64) * period
    rel = (val.t_ns - val.t_ns[0]) if val.t_ns is not None else np.arange(len(val.y), dtype=np.int64) * period
    return np.concatenate([t_est, t_est[-1] + period + rel]).astype(np.int64)


def load_dataset(
    path: str | os.PathLike[str],
    inputs: list[str] | tuple[str, ...],
    output: str,
    *,
    est: int | None = None,
    est_fraction: float | None = None,
    stream: str | None = None,
    delimiter: str | None = None,
    missing: str = "error",
    allow_time_input: bool = False,
    validation: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
) -> Dataset:
    """Load the named columns, check them, handle missing values, and split them (estimation first).

    Parameters
    ----------
    path : path-like
    inputs : list of str
        Input column names (at least one).
    output : str
        Output column name.
    est, est_fraction : optional
        Estimation samples (count or fraction, of the samples kept); default the first half.
    stream : str, optional
        Stream of an MCAP log.
    delimiter : str, optional
        CSV delimiter; default detected (:mod:`streamid.logs.csv_table`).
    missing : {"error", "drop", "fill"}
        Rows with a missing value (empty cell, NaN) in a column used: an error naming
        them (default), left out, or filled by linear interpolation
        (:func:`streamid.logs.columns.handle_missing`).
    allow_time_input : bool
        Use an input that only increases or decreases (a time column?) with a warning
        instead of refusing it.
    validation : path-like, optional
        A second file with the same columns (another experiment): all of ``path`` is then the
        estimation data and this file the validation data, read with the same settings
        (``est``/``est_fraction`` must not be given).  Its times are drawn after the estimation
        data's; the two files must have one sample period.
    progress : optional
        Called as ``progress(rows_read, rows_at_most)`` while each file is read.

    Raises
    ------
    DataError
        Unknown columns, columns of different lengths, infinite values, missing values
        (``missing="error"``), an input that is the output, a time-like input; with
        ``validation``: a split given as well, or two sample periods.
    """
    if validation is not None and (est is not None or est_fraction is not None):
        raise DataError("a validation file and a split of the data were both given: with a validation file all of "
                        "the data file is estimation data; give one or the other (--validate, or --est/--est-fraction)")
    def read(file: str | os.PathLike[str]) -> Record:
        return load_record(file, inputs, output, stream=stream, delimiter=delimiter, missing=missing,
                           allow_time_input=allow_time_input, progress=progress)

    rec = read(path)
    if validation is None:
        k = split_index(len(rec.y), est, est_fraction)
        return Dataset(rec.path, rec.input_names, output, rec.u[:k], rec.y[:k], rec.u[k:], rec.y[k:], k, rec.t_ns,
                       notes=rec.notes, info=rec.info, period_ns=rec.period_ns)
    val = read(validation)
    _same_period(rec, val)
    same = os.path.realpath(path) == os.path.realpath(validation)
    notes = rec.notes + val.notes + ((f"the validation file is the data file {rec.path}: the model is judged on "
                                      f"the samples it was fitted to, not on data it never saw",) if same else ())
    return Dataset(rec.path, rec.input_names, output, rec.u, rec.y, val.u, val.y, len(rec.y), _joined_times(rec, val),
                   notes=notes, info={**rec.info, "validation": {"path": val.path, **val.info}},
                   period_ns=rec.period_ns or val.period_ns, validation_path=val.path)
