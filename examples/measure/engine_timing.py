"""Seconds and validation free-run R² of the default identification of one suite system, seed by seed.

Usage: ``python examples/measure/engine_timing.py SYSTEM SEEDS [both|numpy|kernel]``

``SYSTEM`` a name of ``benchmarks.suite.SYSTEMS`` (e.g. ``bouc_wen``: 10,000 estimation samples), ``SEEDS``
comma-separated. ``both`` (default): both cores, the evaluation helper as ``streamid identify`` uses it.
``numpy`` / ``kernel``: one core, the activations' ``exp2`` and the search's Gram by numpy (its BLAS) or by the
compiled kernels (``streamid.engine.fit.rbf.NUMPY_PATH``, set in this process only): an A/B of the two on this machine.
Prints one line per seed and the median seconds (docs/benchmarks.md quotes it).
"""

from __future__ import annotations

import contextlib
import statistics
import sys

import streamid.engine.fit.rbf as rbf
from benchmarks.suite import SYSTEMS, identify_target
from streamid.engine.search.parallel import EvalHelper
from streamid.engine.settings import DEFAULT


def main(system: str, seeds: list[int], mode: str = "both") -> float:
    if mode not in ("both", "numpy", "kernel"):
        raise SystemExit(f"mode must be one of both, numpy, kernel; got {mode!r}")
    if mode != "both":
        rbf.NUMPY_PATH = mode == "numpy"
    target = SYSTEMS[system]()[0]
    secs = []
    with EvalHelper() if mode == "both" and EvalHelper.supported() else contextlib.nullcontext() as helper:
        for s in seeds:
            r = identify_target(target, DEFAULT, s, helper=helper)
            secs.append(r["seconds"])
            print(f"{target.name} seed {s}: {r['seconds']:.2f} s, validation FR R2 {r['fr_val']:.4f}", flush=True)
    med = statistics.median(secs)
    print(f"median {med:.2f} s over {len(secs)} seeds ({mode})")
    return med


if __name__ == "__main__":
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    main(sys.argv[1], [int(s) for s in sys.argv[2].split(",")], sys.argv[3] if len(sys.argv) > 3 else "both")
