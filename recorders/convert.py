"""Convert the real data sets shipped with streamid into MCAP logs.

Usage (from the repository root; the defaults are the copies in ``tests/data``)::

    python -m recorders.convert                       # every log into streamid/data/
    python -m recorders.convert mr_damper SRC.mat OUT.mcap
    python -m recorders.convert piezo_p885 SRC.dat OUT.mcap
    python -m recorders.convert f16_gvt SRC_DIR OUT.mcap     # SRC_DIR holds f16_est.csv, f16_val.csv
    python -m recorders.convert cstr SRC.csv OUT.mcap

The values in the logs are the source values exactly (float64 from the MAT
file; the nearest float64 of each decimal number in the DAT and CSV files);
only timing (sample index x the sampling period) and names/units are added.
Each log carries its source and licence in its ``streamid`` metadata record,
and the ``PROVENANCE.md`` text is kept beside it.

================  ==============================  ===============================================  =======
log               input                           outputs                                          rate
================  ==============================  ===============================================  =======
mr_damper         velocity_cm_s                   force_N                                          200 Hz
piezo_p885        voltage_V                       displacement_um                                  200 Hz
f16_gvt           force_N                         accel1_au, accel2_au, accel3_au                  400 Hz
cstr              coolant_flow_l_min              concentration_mol_l, temperature_K               1/6 Hz
================  ==============================  ===============================================  =======
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError, StreamidError
from streamid.logs import write_arrays_log

__all__ = ["RealLog", "REAL_LOGS", "load_mr_damper", "load_piezo_p885", "load_f16_gvt", "load_cstr", "convert"]

PERIOD_NS = 5_000_000  # mr_damper and piezo_p885: Ts = 0.005 s (200 Hz)
BATCH = 20  # 100 ms per batch
F16_PERIOD_NS = 2_500_000  # fs = 400 Hz
F16_PERIOD_SAMPLES = 8192  # one multisine period per file
CSTR_PERIOD_NS = 6_000_000_000  # Ts = 0.1 min

Arrays = dict[str, NDArray[np.float64]]


def _read_csv(path: Path, header: Sequence[str]) -> NDArray[np.float64]:
    """Rows of a comma-separated file with exactly ``header``; each field parsed by Python's ``float``."""
    expected = ",".join(header)
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: must be a readable ASCII CSV file with header {expected!r}; {exc}") from exc
    if not lines or lines[0].strip() != expected:
        got = lines[0].strip()[:80] if lines else "an empty file"
        raise DataError(f"{path}: the header row must be {expected!r}; got {got!r}")
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split(",")
        try:
            if len(fields) != len(header):
                raise ValueError(f"{len(fields)} fields")
            rows.append([float(f) for f in fields])
        except ValueError as exc:
            raise DataError(f"{path}: line {i} must hold {len(header)} comma-separated numbers; "
                            f"got {line[:80]!r} ({exc})") from None
    if not rows:
        raise DataError(f"{path}: no data rows after the header {expected!r}")
    data = np.array(rows, dtype=np.float64)
    if not np.all(np.isfinite(data)):
        r, c = np.argwhere(~np.isfinite(data))[0]
        raise DataError(f"{path}: line {r + 2}, column {header[c]!r} must be finite; got {float(data[r, c])!r}")
    return data


def load_mr_damper(path: str | os.PathLike[str]) -> tuple[Arrays, Arrays]:
    """``{velocity_cm_s}``, ``{force_N}`` of ``Magneto.mat``: ``[U; U_val]``, ``[Y; Y_val]``."""
    from scipy.io import loadmat

    try:
        m = loadmat(str(path))
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: must be the MATLAB file Magneto.mat with U, Y, U_val, Y_val; {exc}") from exc
    missing = [k for k in ("U", "Y", "U_val", "Y_val") if k not in m]
    if missing:
        raise DataError(f"{path}: Magneto.mat must hold U, Y, U_val, Y_val; missing {missing}")
    v = np.concatenate([np.asarray(m["U"], np.float64).ravel(), np.asarray(m["U_val"], np.float64).ravel()])
    f = np.concatenate([np.asarray(m["Y"], np.float64).ravel(), np.asarray(m["Y_val"], np.float64).ravel()])
    return {"velocity_cm_s": v}, {"force_N": f}


def load_piezo_p885(path: str | os.PathLike[str]) -> tuple[Arrays, Arrays]:
    """``{voltage_V}`` (column 1) and ``{displacement_um}`` (sensor, column 5) of ``Model_Vi_Do.dat``."""
    try:
        data = np.loadtxt(str(path), dtype=np.float64, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: must be Model_Vi_Do.dat, 7 whitespace-separated numeric columns; {exc}") from exc
    if data.shape[1] != 7:
        raise DataError(f"{path}: Model_Vi_Do.dat must have 7 columns; got {data.shape[1]}")
    return {"voltage_V": data[:, 0].copy()}, {"displacement_um": data[:, 4].copy()}


_F16_HEADER = ("Force", "Acceleration1", "Acceleration2", "Acceleration3")


def load_f16_gvt(path: str | os.PathLike[str]) -> tuple[Arrays, Arrays]:
    """F-16 GVT: ``f16_est.csv`` then ``f16_val.csv`` of the folder ``path`` (8192 rows each).

    Input ``force_N`` (shaker force); outputs ``accel1_au``, ``accel2_au``, ``accel3_au``
    (Acceleration1-3: excitation point, wing next to the payload interface, payload; the
    benchmark does not state their unit, hence ``au``).
    """
    folder = Path(path)
    parts = []
    for name in ("f16_est.csv", "f16_val.csv"):
        data = _read_csv(folder / name, _F16_HEADER)
        if data.shape[0] != F16_PERIOD_SAMPLES:
            raise DataError(f"{folder / name}: must hold one multisine period, {F16_PERIOD_SAMPLES} rows; "
                            f"got {data.shape[0]}")
        parts.append(data)
    data = np.concatenate(parts)
    return ({"force_N": data[:, 0].copy()},
            {f"accel{i}_au": data[:, i].copy() for i in (1, 2, 3)})


_CSTR_HEADER = ("t_min", "q", "Ca", "T")


def load_cstr(path: str | os.PathLike[str]) -> tuple[Arrays, Arrays]:
    """DaISy CSTR (simulated): ``{coolant_flow_l_min}``, ``{concentration_mol_l, temperature_K}``.

    The time column ``t_min`` must be ``0.1, 0.2, ...`` (Ts = 0.1 min); it is not copied (the
    log's sample times are ``k`` x 6 s from 6 s, the same instants).
    """
    p = Path(path)
    data = _read_csv(p, _CSTR_HEADER)
    expected = 0.1 * np.arange(1, data.shape[0] + 1)
    bad = np.flatnonzero(np.abs(data[:, 0] - expected) > 1e-9)
    if bad.size:
        i = int(bad[0])
        raise DataError(f"{p}: t_min must step by 0.1 min from 0.1; line {i + 2} has {float(data[i, 0])!r}, "
                        f"expected {expected[i]:.1f}")
    return ({"coolant_flow_l_min": data[:, 1].copy()},
            {"concentration_mol_l": data[:, 2].copy(), "temperature_K": data[:, 3].copy()})


@dataclass(frozen=True)
class RealLog:
    """One real data set and how it becomes a log.

    ``source_file`` is relative to ``tests/data`` (a folder for f16_gvt); ``loader``
    returns the inputs and outputs by channel name; ``t0_ns`` is the first sample's time.
    """

    name: str
    source_file: str
    loader: Callable[[str | os.PathLike[str]], tuple[Arrays, Arrays]]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    period_ns: int
    batch_size: int
    metadata: tuple[tuple[str, str], ...]
    t0_ns: int = 0

    def load(self, path: str | os.PathLike[str]) -> tuple[Arrays, Arrays]:
        inputs, outputs = self.loader(path)
        if tuple(inputs) != self.inputs or tuple(outputs) != self.outputs:  # pragma: no cover - a loader bug
            raise DataError(f"{self.name}: loader gave channels {list(inputs)} -> {list(outputs)}, "
                            f"expected {list(self.inputs)} -> {list(self.outputs)}")
        return inputs, outputs

    @property
    def input_name(self) -> str:
        """The first input channel."""
        return self.inputs[0]

    @property
    def output_name(self) -> str:
        """The first output channel."""
        return self.outputs[0]


_F16_SOURCE = ("forgi86/dynonet @ 0bdf70605da2570cca526659b3b21e6356e7bb48, paths "
               "examples/F16GVT/data/BenchmarkData/F16Data_FullMSine_Level3.csv (estimation) and "
               "F16Data_FullMSine_Level2_Validation.csv (validation); the files were deleted in the next commit")

REAL_LOGS: dict[str, RealLog] = {
    "mr_damper": RealLog(
        "mr_damper", "mr_damper/Magneto.mat", load_mr_damper, ("velocity_cm_s",), ("force_N",), PERIOD_NS, BATCH,
        (
            ("source", "measured: MR damper, MATLAB System Identification Toolbox mrdamper data "
                       "via Magneto.mat (U=V(1:2000), U_val=V(2001:end), Y=F(1:2000), Y_val=F(2001:end))"),
            ("source_repository", "hibames/Nonlinear-System-Identification-Using-Autoencoders-for-MPC "
                                  "@ caf1cf628cedad56cd80c1b6cd849422fb42b36d, path Magneto.mat"),
            ("cross_check", "gsmfnc/LPV_SysId @ a843d61efb1401308c932bd77b6653446bbdd351 "
                            "(BSD-3-Clause), bit-identical arrays"),
            ("licence", "no licence file in the source repository; original data MathWorks toolbox "
                        "example data; see mr_damper.PROVENANCE.md"),
            ("input", "velocity_cm_s: damper velocity, cm/s"),
            ("output", "force_N: damper force, N"),
            ("period_ns", "5000000 (Ts = 0.005 s, from the MATLAB example; not stored in the file)"),
            ("estimation_samples", "2000 (samples 2000.. are the example's validation part)"),
        ),
    ),
    "piezo_p885": RealLog(
        "piezo_p885", "piezo_p885/Model_Vi_Do.dat", load_piezo_p885, ("voltage_V",), ("displacement_um",),
        PERIOD_NS, BATCH,
        (
            ("source", "measured: PI PICMA P-885.91 piezo stack, 1 Hz sine, Aye & Ang ICSTSD 2018"),
            ("source_repository", "yan9a/DiscreteBacklashOperator @ 79fd060d86cdf69be2388e29bf57b0766c273650, "
                                  "path MatLabCode/DiscreteBacklashModel/Model_Vi_Do.dat"),
            ("licence", "MIT License, Copyright (c) 2019 Yan Naing Aye; see piezo_p885.PROVENANCE.md"),
            ("input", "voltage_V: actuator input voltage, V (column 1)"),
            ("output", "displacement_um: capacitive sensor displacement, um, arbitrary offset (column 5)"),
            ("period_ns", "5000000 (Fs = 200 Hz in Step01_GetModel.m)"),
            ("note", "the author's script treats the output as lagging the input by one sample"),
        ),
    ),
    "f16_gvt": RealLog(
        "f16_gvt", "f16_gvt", load_f16_gvt, ("force_N",), ("accel1_au", "accel2_au", "accel3_au"),
        F16_PERIOD_NS, 32,  # 80 ms per batch; 8192 = 256 batches: the junction falls between two
        (
            ("source", "measured: F-16 ground vibration test benchmark (Noel & Schoukens, Workshop on "
                       "Nonlinear System Identification Benchmarks 2017), full-grid multisine 2-15 Hz; "
                       "the last (9th) period of level 3 (36.8 N RMS) then of level 2 (24.6 N RMS)"),
            ("source_repository", _F16_SOURCE),
            ("licence", "no licence file in the source repository at that commit; no licence terms in the "
                        "benchmark description; cite Noel & Schoukens 2017; see f16_gvt.PROVENANCE.md"),
            ("input", "force_N: shaker force at the excitation point (impedance head), N"),
            ("output", "accel1_au: acceleration at the excitation point; accel2_au: right wing next to the "
                       "payload interface; accel3_au: payload next to the interface; unit not stated by "
                       "the benchmark (au)"),
            ("period_ns", "2500000 (fs = 400 Hz, benchmark description)"),
            ("estimation_samples", "8192 (samples 0-8191: level 3, estimation; 8192-16383: level 2, "
                                   "validation; each one steady-state period, periodic)"),
            ("rows", "source rows 65537-73728 of each benchmark file (the 9th of 9 periods)"),
        ),
    ),
    "cstr": RealLog(
        "cstr", "cstr/cstr.csv", load_cstr, ("coolant_flow_l_min",), ("concentration_mol_l", "temperature_K"),
        CSTR_PERIOD_NS, 10,  # 1 min per batch
        (
            ("source", "SIMULATED: DaISy cstr.dat, continuous stirred tank reactor (exothermic reaction, "
                       "concentration controlled by the coolant flow), contributed by Jairo Espinosa"),
            ("source_repository", "forgi86/sysid-neural-structures-fitting @ "
                                  "886c969c03e86422b8a81d9e826b5745a4934bb0, path "
                                  "examples/CSTR_example/data/cstr.dat"),
            ("licence", "MIT License, Copyright (c) 2019 Marco Forgione (source repository); "
                        "see cstr.PROVENANCE.md"),
            ("input", "coolant_flow_l_min: coolant flow q, l/min"),
            ("output", "concentration_mol_l: concentration Ca, mol/l; temperature_K: temperature T, K"),
            ("period_ns", "6000000000 (Ts = 0.1 min, DaISy); t_ns = t_min x 60 s, from 6 s"),
            ("estimation_samples", "3750 (the first half; the second half for validation)"),
        ),
        t0_ns=CSTR_PERIOD_NS,
    ),
}


def convert(name: str, source: str | os.PathLike[str], output: str | os.PathLike[str]) -> int:
    """Convert the real data set ``name`` from ``source`` into the log ``output``; return samples."""
    spec = REAL_LOGS.get(name)
    if spec is None:
        raise DataError(f"data set must be one of {', '.join(REAL_LOGS)}; got {name!r}")
    inputs, outputs = spec.load(source)
    meta = dict(spec.metadata)
    meta["converted_by"] = "python -m recorders.convert"
    meta["source_file"] = Path(source).name
    write_arrays_log(output, name, inputs, outputs, period_ns=spec.period_ns, t0_ns=spec.t0_ns,
                     batch_size=spec.batch_size, metadata=meta)
    return int(next(iter(inputs.values())).shape[0])


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m recorders.convert", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", nargs="?", choices=sorted(REAL_LOGS), help="data set (default: all)")
    p.add_argument("source", nargs="?", help="source file (default: tests/data/<set>/...)")
    p.add_argument("output", nargs="?", help="output log (default: streamid/data/<set>.mcap)")
    args = p.parse_args(argv)
    names = [args.name] if args.name else sorted(REAL_LOGS)
    if (args.source or args.output) and not args.name:
        p.error("give the data set name with a source/output")
    try:
        for name in names:
            src = Path(args.source) if args.source else Path("tests/data") / REAL_LOGS[name].source_file
            out = Path(args.output) if args.output else Path("streamid/data") / f"{name}.mcap"
            n = convert(name, src, out)
            print(f"{name}: {n} samples from {src} -> {out}")
    except StreamidError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
