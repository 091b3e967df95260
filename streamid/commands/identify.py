"""streamid identify: identify an RBF-NARX model from a data file (CSV, MAT or MCAP log).

Examples:

    streamid identify data.csv --input u --output y
    streamid identify mr_damper --est 2000 --model mr.json     # a bundled log: its input and output
    streamid identify data.csv --input u --output y --rrd r.rrd && streamid view r.rrd
    streamid identify data.csv --input u --output y --paper --runs 10 --report r.json
    streamid identify sweep1.csv --validate sweep2.csv --input u --output y --model m.json

Reading a CSV: the delimiter (, ; tab | whitespace) is detected from the header
and the first lines (--delimiter sets it); with ; tab | or whitespace a decimal
comma (1,5) is read as such. A column named like a time (time_s, t_ms...) that
only increases is the samples' clock. Missing values (empty cells, NaN, NA) in
the columns used are an error naming their file lines, unless --fill (linear
interpolation between the neighbouring samples of the column) or --drop (the
rows are left out: the sample spacing is broken where rows inside the record
go, which is refused at more than one place per 100 rows). Either way missing
rows at the start and end are cut. An input that is the output, or that only
ever increases or decreases (a time column?) is refused; --allow-time-input
uses the latter anyway, with a warning.

Estimation data are the first samples (--est N or --est-fraction F, default
half), validation data the rest; or --validate VAL: all of DATA is estimated on
and VAL, a second experiment with the same columns and sample period (another
excitation is the real test), validated on. A model saved with --model can be
judged on any later record with streamid validate. With --runs R the identification is repeated
with seeds S .. S+R-1 (in parallel over --workers processes) and the fitness
statistics are reported like the paper's Table 4.  How to read the output:
the README's "Your own data file" section and docs/method.md.
"""

from __future__ import annotations

import argparse
from typing import Any

from streamid.commands.identify_io import add_reading_flags, data_help
from streamid.engine.settings import DEFAULT, MORE_BELOW, PAPER, REFINE_ABOVE, SELECTIONS, CoEAConfig
from streamid.errors import ConfigError

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "identify",
        help="identify an RBF-NARX model from a CSV, MAT or MCAP file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("data", metavar="DATA", help=data_help())
    p.add_argument("--input", action="append", metavar="COL",
                   help="input column (repeat for several; an MCAP log's default: its stream's inputs)")
    p.add_argument("--output", metavar="COL", help="output column (an MCAP log's default: its stream's only output)")
    add_reading_flags(p)
    split = p.add_mutually_exclusive_group()
    split.add_argument("--est", type=int, metavar="N", help="estimation samples: the first N (default: half)")
    split.add_argument("--est-fraction", type=float, metavar="F", help="estimation samples: the first fraction F")
    split.add_argument("--validate", metavar="VAL",
                       help="validation data from a second file (or bundled log) with the same columns, e.g. an "
                            "experiment with another excitation: all of DATA is then the estimation data")
    p.add_argument("--stream", help="stream of an MCAP log holding several")
    p.add_argument(
        "--paper",
        action="store_true",
        help="the paper's procedure: one run chosen by fitness, defaults M=10, G=400 (else streamid's defaults)",
    )
    p.add_argument("--neurons", type=int, metavar="M", help=f"RBF neurons (default {DEFAULT.neurons}; --paper {PAPER.neurons})")
    p.add_argument("--max-lag", type=int, metavar="L", help="largest candidate lag of the output and of every input (default 10)")
    p.add_argument("--max-lag-y", type=int, metavar="LY", help="largest candidate lag of the output (default: --max-lag, or 10)")
    p.add_argument("--max-lag-u", type=int, metavar="LU", help="largest candidate lag of every input (default: --max-lag, or 10)")
    p.add_argument(
        "--generations", type=int, metavar="G", help=f"generations per run (default {DEFAULT.generations}; --paper {PAPER.generations})"
    )
    p.add_argument("--population", type=int, metavar="P", help="size of both populations (default 20)")
    p.add_argument(
        "--lag-search-neurons",
        type=int,
        metavar="M1",
        help=f"two-stage runs: neurons of the lag-search stage, 0 = one stage (default {DEFAULT.lag_search_neurons}; --paper 0)",
    )
    p.add_argument("--restarts", type=int, metavar="K", help=f"coevolution runs per identification (default {DEFAULT.restarts}; --paper 1)")
    p.add_argument("--direct-terms", choices=("test", "on", "off"),
                   help="each input's u(t) among the candidate lags: test (the default: when a likelihood-ratio test of "
                        "a linear ARX model finds the output responds within the sample), on (always) or off (the paper: "
                        "u(t-1) on; --paper)")
    p.add_argument("--more-restarts", type=int, metavar="N",
                   help=f"N more runs when the best run's estimation free-run R2 is between 0 and {MORE_BELOW} "
                        f"(a record explained in part; default {DEFAULT.more_restarts}; 0: never; --paper 0)")
    p.add_argument("--ensembles", action=argparse.BooleanOptionalAction, default=None,
                   help="the restarts combined: the means of the best 2, 3 and all admissible restarts' networks compete "
                        "in the final choice by the same criterion, then the median of the finished restarts' networks "
                        "is kept unless the chosen model has a long linear part (at least three restarts; default "
                        f"{'on' if DEFAULT.run_ensembles else 'off'}; never with --paper)")
    p.add_argument("--linear", action=argparse.BooleanOptionalAction, default=None,
                   help="every candidate network is also offered with a direct linear part a'r + b over its regressors, "
                        "the kind chosen by the same criterion (default "
                        f"{'on' if DEFAULT.linear_terms else 'off'}; never with --paper)")
    p.add_argument("--long-linear", type=int, metavar="N", dest="long_linear",
                   help="where the networks explain the estimation record in part (free-run R2 below "
                        f"{MORE_BELOW}), offer the kept network with a dense linear ARX part of order up to N, "
                        f"the order chosen by the same criterion, and the means of the best 2 and 3 such candidates compete "
                        f"(default {DEFAULT.long_linear}; 0: off; never with --paper)")
    p.add_argument("--refine", type=int, metavar="N",
                   help="at most N iterations fitting the kept model's weights to its free run on the estimation data, "
                        f"when that free run's R2 is at least {REFINE_ABOVE} (default {DEFAULT.refine_iterations}; "
                        "0: off, the search's one-step weights; never with --paper)")
    p.add_argument("--selection", choices=SELECTIONS, help=f"how the final model is chosen among candidates (default {DEFAULT.selection})")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the first run (default 0)")
    p.add_argument("--runs", type=int, default=1, metavar="R", help="independent identifications, seeds S..S+R-1 (default 1)")
    p.add_argument("--workers", type=int, default=2, metavar="W", help="processes (default 2; 1 = this process only)")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON line on stdout instead of the table (as every streamid command's --json)")
    p.add_argument("--report", metavar="REPORT.json", help="also write the report as a JSON file")
    p.add_argument("--model", metavar="MODEL.json", help="write the best run's model (JSON: streamid.model/1, /2 with a linear part, /3 for a mean of networks, "
                        "/4 with a long linear part)")
    p.add_argument("--rrd", metavar="FILE.rrd",
                   help="draw the kept model in the daemon's Rerun layout into FILE.rrd (streamid view FILE.rrd)")
    p.add_argument("--progress", choices=("auto", "always", "never"), default="auto", help="progress bar on stderr (auto: on a terminal, after a second; always: from the start); one identification moves it every generation "
                        "(its restarts then run in this process), --runs over several processes every finished run")
    p.set_defaults(func=run)


def _config(args: argparse.Namespace) -> CoEAConfig:
    base = PAPER if args.paper else DEFAULT
    changes: dict[str, Any] = {}
    for flag, field in (
        ("neurons", "neurons"),
        ("generations", "generations"),
        ("population", "population"),
        ("restarts", "restarts"),
        ("more_restarts", "more_restarts"),
        ("selection", "selection"),
        ("lag_search_neurons", "lag_search_neurons"),
    ):
        v = getattr(args, flag)
        if v is not None:
            changes[field] = v
    if args.max_lag is not None:
        changes["max_lag_y"] = changes["max_lag_u"] = args.max_lag
    if args.max_lag_y is not None:
        changes["max_lag_y"] = args.max_lag_y
    if args.max_lag_u is not None:
        changes["max_lag_u"] = args.max_lag_u
    if any(v is not None for v in (args.max_lag, args.max_lag_y, args.max_lag_u)):
        changes["max_lag_cap"] = 0  # lags as given, not chosen from the data
    if args.direct_terms is not None:
        if args.paper and args.direct_terms != "off":
            raise ConfigError(f"--direct-terms {args.direct_terms} adds u(t) to the candidate lags; --paper keeps the "
                              "paper's u(t-1) on (drop one of the two)")
        changes["direct_terms"] = args.direct_terms
    if args.ensembles is not None:
        if args.paper and args.ensembles:
            raise ConfigError("--ensembles averages several restarts' networks; --paper makes one run chosen by fitness "
                              "(drop one of the two)")
        changes["run_ensembles"] = bool(args.ensembles)
    if args.linear is not None:
        if args.paper and args.linear:
            raise ConfigError("--linear offers networks with a direct linear part; --paper keeps the paper's RBF "
                              "network (drop one of the two)")
        changes["linear_terms"] = bool(args.linear)
    if args.long_linear is not None:
        if args.paper and args.long_linear:
            raise ConfigError(f"--long-linear offers a dense linear ARX part; --paper keeps the paper's RBF network "
                              f"(drop one of the two); got --long-linear {args.long_linear}")
        changes["long_linear"] = args.long_linear
    if args.refine is not None:
        if args.paper and args.refine:
            raise ConfigError(f"--refine fits the weights to the free run; --paper keeps the paper's least squares "
                              f"(drop one of the two); got --refine {args.refine}")
        changes["refine_iterations"] = args.refine
    if args.workers < 1:
        raise ConfigError(f"--workers must be an integer >= 1; got {args.workers}")
    if args.runs < 1:
        raise ConfigError(f"--runs must be an integer >= 1; got {args.runs}")
    if args.seed < 0:
        raise ConfigError(f"--seed must be an integer >= 0; got {args.seed}")
    try:
        return base.replace(**changes)
    except ConfigError as exc:
        raise ConfigError(f"{exc} (check the command-line options)") from None


def run(args: argparse.Namespace) -> int:
    """Identify as the options say (the work is in :mod:`streamid.commands.identify_run`, imported only now:
    the engine, numba and scipy cost other commands' ``--help`` nothing)."""
    from streamid.commands.identify_run import identify_command

    return identify_command(args, _config(args))
