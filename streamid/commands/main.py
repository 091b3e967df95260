"""The ``streamid`` command: one entry point, one subcommand per job.

Subcommands are small modules exposing ``register(subparsers)``; each adds its
parser and sets ``func`` (``func(args) -> int``).  Commands that belong to the
packages around streamid (``recorders`` provides ``record`` and ``simulate``,
``replay`` provides ``replay``, and :mod:`benchmarks` provides ``bench``) register themselves through the
``streamid.commands`` entry-point group, so that no product module imports them:
data flows one way, and those packages depend on streamid, not the reverse.
"""

from __future__ import annotations

import argparse
import os
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn
from importlib.metadata import entry_points

from streamid._version import __version__
from streamid.commands.helptext import plain_parser
from streamid.errors import StreamidError

#: Subcommands that live inside streamid itself, in the order ``--help`` lists them.
BUILTIN_COMMANDS: tuple[str, ...] = (
    "streamid.commands.identify",
    "streamid.commands.validate",
    "streamid.commands.export",
    "streamid.commands.daemon",
    "streamid.commands.watch",
    "streamid.commands.status",
    "streamid.commands.demo",
    "streamid.commands.router",
    "streamid.commands.view",
)

ENTRY_POINT_GROUP = "streamid.commands"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``streamid`` parser with every subcommand, or with ``command``'s alone when it names one.

    A subcommand is named by its module (``streamid.commands.NAME``) or its entry point (``NAME``). Importing
    every command's module costs about 0.3 s (``streamid --help`` 0.45 s; 1.9 s before the commands and the
    simulators moved the engine and scipy into the code that runs), which ``streamid status`` need not pay:
    with ``command`` only its own is imported (``--help``, no command or an unknown one still list them all).
    ``tests/test_public_api.py`` keeps the engine's solver, numba and scipy out of every parser."""
    parser = argparse.ArgumentParser(
        prog="streamid",
        description=(
            "Streaming online nonlinear system identification: coevolutionary "
            "RBF-NARX models fitted from samples on Eclipse Zenoh or from logs."
        ),
    )
    parser.add_argument("--version", action="version", version=f"streamid {__version__}")
    sub = parser.add_subparsers(title="commands", dest="command", metavar="COMMAND")
    builtins = BUILTIN_COMMANDS
    eps = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name)
    if command is not None and (f"streamid.commands.{command}" in builtins or any(e.name == command for e in eps)):
        builtins = tuple(m for m in builtins if m == f"streamid.commands.{command}")
        eps = [e for e in eps if e.name == command]
    for name in builtins:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # command not built yet in this tree
                continue
            raise
        module.register(sub)
    for ep in eps:
        ep.load()(sub)
    for command_parser in sub.choices.values():  # descriptions come from reST docstrings
        plain_parser(command_parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(words[0] if words and not words[0].startswith("-") else None)
    args, extra = parser.parse_known_args(words)
    if extra:  # said by the command's own parser: its usage, not the top level's, shows what it accepts
        subs = next((a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction)), {})
        (subs.get(str(getattr(args, "command", None))) or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except StreamidError as exc:
        print(f"streamid {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


def console_main() -> None:
    """Entry point of the ``streamid`` command and of ``python -m streamid``.

    Runs :func:`main`, flushes standard output and error, and leaves with
    ``os._exit``: by then every command has closed its Zenoh sessions and
    flushed its files, and skipping interpreter finalisation avoids a race in
    which a Zenoh runtime thread, still releasing a Python callback, tries to
    take the GIL while the interpreter is being torn down (the process then
    aborts with "FATAL: exception not rethrown", seen once in CI).
    """
    try:
        rc = main()
    except SystemExit as exc:  # argparse --help / usage errors
        rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    except BrokenPipeError:  # the reader of standard output went away (``streamid watch | head``): stop quietly
        rc = BROKEN_PIPE
    if rc == BROKEN_PIPE or _stdout_gone():
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # what is still buffered goes nowhere
        rc = BROKEN_PIPE
    leave(rc)


#: Exit status after the reader of standard output went away: 128 + SIGPIPE, as a shell reports a process that
#: signal ended (a Python process ignores SIGPIPE and gets EPIPE instead).
BROKEN_PIPE = 141


def _stdout_gone() -> bool:
    """Whether flushing standard output fails because its reader has gone (the rest of the output is lost)."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        return True
    except (OSError, ValueError):
        return False
    return False


def leave(rc: int) -> NoReturn:
    """Flush standard output and error and end the process with ``os._exit(rc)`` (why: :func:`console_main`).
    For any process of streamid's that has used Zenoh and closed its sessions (the command, a test's daemon or
    publisher process)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(rc)
