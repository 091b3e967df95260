"""streamid validate: judge a saved model on a record it has never seen.

Examples:

    streamid identify sweep1.csv --input u --output y --model m.json
    streamid validate m.json sweep2.csv                      # the model's own signal names are the columns
    streamid validate m.json log.mcap --min-r2-fr 0.9        # exit status 1 when the free run is below 0.9
    streamid validate m.json log.mcap --start 10 --end 60    # only 10-60 s of the log (times need a clock)
    streamid validate m.json run.csv --input volts --output pos --rrd v.rrd && streamid view v.rrd

MODEL is a model file: streamid identify's --model, Model.save, or a model-update
document a subscriber received from the daemon (its model is read). DATA is read
as streamid identify reads it (CSV, MAT or MCAP log, or a bundled log's name);
its columns default to the model's input and output names. The model runs free
from the record's first max_lag measured outputs (the simulation a controller
designer relies on) and one step ahead; the report gives R² over the samples
after those, the fit in per cent (100 (1 - |y - yhat| / |y - mean y|), as the
System Identification Toolbox's compare) and the RMSE, the five correlation tests
of the one-step residual, and caveats: signals beyond the range the model was
estimated on (a Gaussian RBF network does not extrapolate), a one-step predictor
that does not simulate. A record sampled at another period than the model's is
refused: a NARX model's lags count samples.

Exit status: 0, or 1 when --min-r2-fr is given and the free run is below it
(2: bad input, as every command).
"""

from __future__ import annotations

import argparse

from streamid.commands.identify_io import add_reading_flags, data_help

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "validate",
        help="judge a saved model on a record it has never seen (free run, one step ahead, residual tests)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("model", metavar="MODEL", help="model JSON file (streamid identify --model, or a model update)")
    p.add_argument("data", metavar="DATA", help=data_help())
    p.add_argument("--input", action="append", metavar="COL",
                   help="input column, one per model input in the model's order (default: the model's input names)")
    p.add_argument("--output", metavar="COL", help="output column (default: the model's output name)")
    p.add_argument("--stream", help="stream of an MCAP log holding several")
    add_reading_flags(p)
    p.add_argument("--start", type=float, metavar="S",
                   help="judge from S seconds after the record's first sample (e.g. past the model's own window)")
    p.add_argument("--end", type=float, metavar="S", help="judge up to S seconds after the record's first sample")
    p.add_argument("--min-r2-fr", type=float, metavar="R2",
                   help="exit with status 1 when the free-run R² is below R2 (a gate for scripts and CI)")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON line on stdout instead of the text (as every streamid command's "
                        "--json)")
    p.add_argument("--report", metavar="REPORT.json", help="also write the report as a JSON file")
    p.add_argument("--rrd", metavar="FILE.rrd",
                   help="draw the record, the free run and the residual tests in the daemon's Rerun layout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Validate as the options say (the work is in :mod:`streamid.commands.validate_run`, imported only now)."""
    from streamid.commands.validate_run import validate_command

    return validate_command(args)
