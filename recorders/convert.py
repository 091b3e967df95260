"""Convert the real data sets shipped with streamid into MCAP logs.

Usage (from the repository root; the defaults are the copies in ``tests/data``)::

    python -m recorders.convert                       # both logs into streamid/data/
    python -m recorders.convert mr_damper SRC.mat OUT.mcap
    python -m recorders.convert piezo_p885 SRC.dat OUT.mcap

The values in the logs are the source values exactly (float64 from the MAT
file; the nearest float64 of each decimal number in the DAT file); only
timing (sample index x 5 ms) and names/units are added.  Each log carries its
source and licence in its ``streamid`` metadata record, and the
``PROVENANCE.md`` text is kept beside it.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from streamid.errors import DataError, StreamidError
from streamid.logs import write_arrays_log

__all__ = ["RealLog", "REAL_LOGS", "load_mr_damper", "load_piezo_p885", "convert"]

PERIOD_NS = 5_000_000  # both data sets: Ts = 0.005 s (200 Hz)
BATCH = 20  # 100 ms per batch


def load_mr_damper(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Velocity (cm/s) and force (N) of ``Magneto.mat``: ``[U; U_val]``, ``[Y; Y_val]``."""
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
    return v, f


def load_piezo_p885(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Voltage (V, column 1) and sensor displacement (um, column 5) of ``Model_Vi_Do.dat``."""
    try:
        data = np.loadtxt(str(path), dtype=np.float64, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: must be Model_Vi_Do.dat, 7 whitespace-separated numeric columns; {exc}") from exc
    if data.shape[1] != 7:
        raise DataError(f"{path}: Model_Vi_Do.dat must have 7 columns; got {data.shape[1]}")
    return data[:, 0].copy(), data[:, 4].copy()


@dataclass(frozen=True)
class RealLog:
    """One real data set and how it becomes a log."""

    name: str
    source_file: str
    input_name: str
    output_name: str
    metadata: tuple[tuple[str, str], ...]

    def load(self, path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return (load_mr_damper if self.name == "mr_damper" else load_piezo_p885)(path)


REAL_LOGS: dict[str, RealLog] = {
    "mr_damper": RealLog(
        "mr_damper", "mr_damper/Magneto.mat", "velocity_cm_s", "force_N",
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
        "piezo_p885", "piezo_p885/Model_Vi_Do.dat", "voltage_V", "displacement_um",
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
}


def convert(name: str, source: str | os.PathLike[str], output: str | os.PathLike[str]) -> int:
    """Convert the real data set ``name`` from ``source`` into the log ``output``; return samples."""
    spec = REAL_LOGS.get(name)
    if spec is None:
        raise DataError(f"data set must be one of {', '.join(REAL_LOGS)}; got {name!r}")
    u, y = spec.load(source)
    meta = dict(spec.metadata)
    meta["converted_by"] = "python -m recorders.convert"
    meta["source_file"] = Path(source).name
    write_arrays_log(output, name, {spec.input_name: u}, {spec.output_name: y},
                     period_ns=PERIOD_NS, t0_ns=0, batch_size=BATCH, metadata=meta)
    return int(u.shape[0])


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
