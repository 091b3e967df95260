"""Load identification data from CSV (header row), MATLAB ``.mat`` or streamid MCAP logs.

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
  ``N x k`` gives columns ``X[0] .. X[k-1]``. MATLAB v7.3 (HDF5) files are not supported.
  Bounded before loading (:mod:`streamid.logs.mat_files`).
* ``.mcap``: a streamid log (see :mod:`streamid.logs.mcap_files`); columns are the
  stream's input and output channel names.

The chosen columns are checked (an input equal to the output, a time column as an
input...) and missing values handled as :mod:`streamid.logs.columns` says.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError
from streamid.logs.columns import MISSING_POLICIES, check_columns, handle_missing
from streamid.logs.csv_table import clock_of, read_delimited, time_unit_ns

__all__ = ["PERIOD_TOLERANCE", "Table", "Dataset", "Record", "load_table", "load_record", "load_dataset", "same_period",
           "split_index"]


@dataclass(frozen=True)
class Table:
    """Numeric columns of a data file (equal lengths), with sample times when the file has them."""

    path: str
    columns: dict[str, NDArray[np.float64]]
    t_ns: NDArray[np.int64] | None = None
    period_ns: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    #: columns that cannot be read as numbers, and why (raised by :meth:`column`, only when one is used)
    unreadable: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def column(self, name: str) -> NDArray[np.float64]:
        """One column; :class:`DataError` naming the available ones if unknown."""
        if name not in self.columns:
            raise DataError(
                f"unknown column {name!r} in {self.path}; available columns: {sorted(self.columns)}"
            )
        if name in self.unreadable:
            raise DataError(self.unreadable[name])
        return self.columns[name]


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


def _read_csv(path: Path, delimiter: str | None = None) -> Table:
    cols, lines, how, unreadable = read_delimited(path, delimiter)
    for name, why in unreadable.items():
        if time_unit_ns(name) is not None:  # a clock column, used whenever it is one: its fault stops the file
            raise DataError(why)
    clock = clock_of(cols)
    t_ns = period_ns = None
    if clock is not None:
        how["clock"] = clock[0]
        t_ns = clock[1]
        period_ns = int(np.median(np.diff(t_ns)))
    return Table(str(path), cols, t_ns=t_ns, period_ns=period_ns, meta={"lines": lines, **how}, unreadable=unreadable)


def _read_mat(path: Path) -> Table:
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


def load_table(
    path: str | os.PathLike[str], *, stream: str | None = None, fmt: str | None = None, delimiter: str | None = None
) -> Table:
    """Read a data file's numeric columns.

    Parameters
    ----------
    path : path-like
        ``.csv``, ``.mat`` or ``.mcap`` file.
    stream : str, optional
        Stream of an MCAP log holding several.
    fmt : {"csv", "mat", "mcap"}, optional
        Format, if the extension does not tell.
    delimiter : str, optional
        CSV delimiter (``,`` ``;`` ``\\t`` ``|`` or ``" "`` for whitespace); default detected.

    Raises
    ------
    DataError
        Unreadable file, non-numeric CSV field, unknown format.
    LogError
        An MCAP log that cannot be read.
    """
    p = Path(path)
    if not p.is_file():
        raise DataError(f"data file {str(path)!r} does not exist (or is not a file)")
    kind = (fmt or p.suffix.lstrip(".")).lower()
    if kind in ("csv", "tsv"):
        return _read_csv(p, delimiter)
    if kind == "mat":
        return _read_mat(p)
    if kind == "mcap":
        return _read_mcap(p, stream)
    raise DataError(f"{path}: unknown data format {kind!r}; accepted: .csv/.tsv (header row), .mat, .mcap")


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
) -> Record:
    """Load the named columns of one file and check them, handling missing values (see :func:`load_dataset`)."""
    if not inputs:
        raise DataError("at least one input column is needed (--input COL)")
    if missing not in MISSING_POLICIES:
        raise DataError(f"missing must be one of {MISSING_POLICIES}; got {missing!r}")
    table = load_table(path, stream=stream, delimiter=delimiter)
    names = list(dict.fromkeys([*inputs, output]))
    cols = {c: table.column(c) for c in names}
    lengths = {c: len(a) for c, a in cols.items()}
    if len(set(lengths.values())) != 1:
        raise DataError(f"{path}: the columns have different lengths {lengths}; all must be equal")
    notes = check_columns(str(path), list(inputs), output, cols, allow_time_input=allow_time_input)
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
                           allow_time_input=allow_time_input)

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
