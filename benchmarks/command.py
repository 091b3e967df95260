"""``streamid bench``: the figures that back streamid's claims, measured here and now.

Prints the machine's description and one table of medians over repeated runs:
identification time and R^2 on the reactor, the real MR damper and the real piezo
logs, scaling in N and M, streaming figures (ingestion, replay -> record, update
latency, cold vs warm updates), and with ``--peers`` the same data fitted by
SysIdentPy in the same run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from collections.abc import Callable, Iterable
from importlib.metadata import entry_points

from benchmarks.kit import BenchOptions, Measurement, format_table, machine_description
from streamid.errors import ConfigError

#: streamid's own providers, ``module:function`` with ``function(options) -> Iterable[Measurement]``.
BUILTIN_PROVIDERS: dict[str, str] = {
    "engine": "benchmarks.engine_cases:bench",
    "peers": "benchmarks.peers:bench",
    "daemon": "benchmarks.daemon_cases:bench",
    "online": "benchmarks.online_cases:bench",
    "suite": "benchmarks.suite:bench",
    "capacity": "benchmarks.capacity:bench",
    "reading": "benchmarks.reading:bench",
    "long": "benchmarks.long_records:bench",
}

#: Sections that take many minutes: run only when named (``--only``; ``--suite`` for the suite).
ON_REQUEST = ("suite", "capacity", "long")

ENTRY_POINT_GROUP = "streamid.benchmarks"


def _load(spec: str) -> Callable[[BenchOptions], Iterable[Measurement]]:
    module, _, attr = spec.partition(":")
    return getattr(importlib.import_module(module), attr)


def providers() -> dict[str, Callable[[BenchOptions], Iterable[Measurement]]]:
    found: dict[str, Callable[[BenchOptions], Iterable[Measurement]]] = {}
    for name, spec in BUILTIN_PROVIDERS.items():
        try:
            found[name] = _load(spec)
        except ModuleNotFoundError:
            continue
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found[ep.name] = ep.load()
    return found


def section_names() -> list[str]:
    """Names of the sections ``--only`` accepts (without importing them)."""
    return sorted({*BUILTIN_PROVIDERS, *(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))})


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "bench",
        help="measure identification and streaming figures on this machine",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--repeat", type=int, default=5, help="runs each figure is the median of (default 5)")
    p.add_argument("--quick", action="store_true", help="small sizes and few runs: a smoke run, not for quoting")
    p.add_argument("--peers", action="store_true", help="also fit the data sets with SysIdentPy (extra 'peers')")
    p.add_argument("--suite", action="store_true",
                   help="only the system suite: per system, free-run validation R2 over 10 seeds of the paper's "
                        "settings and the defaults, the 90 %% band's coverage and width and the silent failures "
                        "(with --peers also SysIdentPy FROLS), seconds per identification")
    p.add_argument("--systems", metavar="A,B",
                   help="with --suite: only these systems (comma-separated; benchmarks/suite.py lists them)")
    p.add_argument("--only", action="append", metavar="SECTION",
                   help=f"run only this section (repeatable); sections: {', '.join(section_names())}")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--json", action="store_true",
                   help="print the machine and the measurements as one JSON line on stdout instead of the table")
    p.add_argument("--report", metavar="FILE", help="also write the machine and the measurements as a JSON file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.repeat < 1:
        raise ConfigError(f"--repeat must be a whole number >= 1, got {args.repeat}")
    systems = tuple(s.strip() for s in (getattr(args, "systems", None) or "").split(",") if s.strip())
    if systems:
        if not getattr(args, "suite", False):
            raise ConfigError("--systems chooses among the systems of --suite; add --suite")
        from benchmarks.suite import SYSTEMS

        unknown = [s for s in systems if s not in SYSTEMS]
        if unknown:
            raise ConfigError(f"--systems takes names among {', '.join(SYSTEMS)} (comma-separated); got "
                              f"{', '.join(map(repr, unknown))}")
    options = BenchOptions(
        repeat=1 if args.quick else args.repeat, quick=args.quick, peers=args.peers, seed=args.seed, systems=systems
    )
    found = providers()
    wanted = list(found) if not args.only else args.only
    if getattr(args, "suite", False):
        wanted = ["suite"]
    elif not args.only:
        wanted = [w for w in wanted if w not in ON_REQUEST]  # long: only on request
    unknown = [w for w in wanted if w not in found]
    if unknown:
        import difflib

        close = [m for u in unknown for m in difflib.get_close_matches(u, list(found), n=1)]
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"--only takes one of {', '.join(sorted(found))}; got {', '.join(map(repr, unknown))}{hint}")
    if not args.peers:
        wanted = [w for w in wanted if w != "peers" or args.only]
    machine = machine_description()
    if not args.json:
        print("streamid bench — " + ", ".join(f"{k}: {v}" for k, v in machine.items()))
    rows: list[Measurement] = []
    failures: list[str] = []
    for name in wanted:
        t0 = time.perf_counter()
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        try:
            got = list(found[name](options))
        except Exception as exc:  # one broken section must not hide the others
            failures.append(f"{name}: {type(exc).__name__}: {exc}")
            print(f"[bench] {name} failed: {exc}", file=sys.stderr, flush=True)
            continue
        rows.extend(got)
        print(f"[bench] {name} done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    doc = {"machine": machine, "measurements": [m.to_dict() for m in rows], "failures": failures}
    if args.json:
        print(json.dumps(doc), flush=True)
    else:
        print(format_table(rows))
        for f in failures:
            print(f"FAILED {f}")
    if args.report:
        with open(args.report, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)
    return 1 if failures else 0
