"""streamid export: a model as an FMI 2.0 co-simulation FMU, or as C99 code, to run where engineers run models.

Examples:

    streamid identify sweep.csv --input u --output y --model m.json
    streamid export m.json --fmu plant.fmu                  # an FMU with a linux64 binary (needs a C compiler)
    streamid export m.json --fmu plant.fmu --sources-only   # its C sources only, to compile elsewhere
    streamid export m.json --c out/ --name plant            # out/plant.h and out/plant.c
    streamid export temp.json conc.json --fmu cstr.fmu      # one FMU output per model (one model per output)

MODEL is a model file (streamid identify --model, Model.save, or a model update from the daemon); several
MODEL files (one per output, the same inputs) make one export with an output each. The FMU has a real
input per model input, a real output per output and a real parameter initial_<output> per output (the
model's initial history, default the middle of the output's range); its default step is the model's
sample period. Timing (docs/export.md): the output at a communication point t_k is the model's sample k,
from the inputs set up to t_k (t_k's own only through a direct term) and the past outputs; the first
max_lag samples are the initial value; fmi2DoStep advances one sample per sample period (a step of n
periods holds the inputs over n samples; other steps are refused). A run equals Model.simulate from
the same constant initial history.

Every model is checked before any file is written; a model file that fails is refused (exit 2).
"""

from __future__ import annotations

import argparse

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "export",
        help="a model as an FMI 2.0 co-simulation FMU (no Python needed to run it) or as C99 code",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("models", nargs="+", metavar="MODEL",
                   help="model JSON file (streamid identify --model, or a model update); one per output")
    p.add_argument("--fmu", metavar="OUT.fmu", help="write an FMI 2.0 co-simulation FMU")
    p.add_argument("--c", metavar="DIR", dest="c_dir", help="write NAME.h and NAME.c into DIR (created if needed)")
    p.add_argument("--name", metavar="NAME",
                   help="the C name and FMU model identifier (a C identifier; default: the FMU's file name, or "
                        "the first model file's name for --c)")
    p.add_argument("--period", type=float, metavar="S",
                   help="the sample period in seconds (default: the one the models were identified at)")
    p.add_argument("--sources-only", action="store_true",
                   help="write the FMU's C sources without compiling a binary (no C compiler needed)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from streamid.model.narx import Model
    from streamid.errors import ConfigError
    from streamid.export import c_identifier, plan_of, write_c, write_fmu
    from streamid.wire.names import printable

    if not args.fmu and not args.c_dir:
        raise ConfigError("say what to write: --fmu OUT.fmu (an FMI 2.0 co-simulation FMU) and/or --c DIR (C99 code)")
    if args.sources_only and not args.fmu:
        raise ConfigError("--sources-only is an option of --fmu (--c never compiles)")
    if args.period is not None and not args.period > 0:
        raise ConfigError(f"--period must be a number of seconds > 0; got {args.period}")
    if args.name is not None and c_identifier(args.name) != args.name:
        raise ConfigError(f"--name must be a C identifier ([A-Za-z_][A-Za-z0-9_]*); got {args.name!r}")
    if args.fmu and not str(args.fmu).endswith(".fmu"):
        raise ConfigError(f"--fmu must name a file ending in .fmu; got {args.fmu!r}")
    models = [Model.load(path) for path in args.models]  # every model checked before anything is written
    fmu_name = args.name or (c_identifier(Path(args.fmu).stem) if args.fmu else "")
    c_name = args.name or c_identifier(Path(args.models[0]).stem)
    plan = plan_of(models, fmu_name or c_name, args.period)  # the models go together: refused here, before any file
    if args.fmu:
        path = write_fmu(models, args.fmu, name=fmu_name, period_s=args.period, sources_only=args.sources_only)
        what = "sources only, no binary" if args.sources_only else "with a binary for this platform"
        print(printable(f"wrote {path} (FMI 2.0 co-simulation, model identifier {fmu_name}, "
                        f"outputs {', '.join(m.output_name for m in models)}; added "
                        f"{', '.join(name for _, name in plan.extras)}; {what})"))  # names escaped
    if args.c_dir:
        h, c = write_c(models, args.c_dir, name=c_name, period_s=args.period)
        print(printable(f"wrote {h} and {c}"))
    return 0
