"""``streamid view``: open the daemon's .rrd diagnostics in the Rerun viewer, render them to PNG, or repair them.

A recording written to FILE.rrd is continued in FILE.001.rrd, FILE.002.rrd...
(the daemon closes a segment every few seconds, see --rrd-rotate-s of
``streamid daemon``).  ``streamid view FILE.rrd`` opens FILE.rrd and all its
segments as one recording (the newest first: the viewer takes the layout of the
first file it opens, and the newest segment has the fullest)::

    streamid view diag.rrd                        # the viewer, on every segment
    streamid view diag.rrd --screenshot diag.png  # rendered headless into a PNG
    streamid view --repair diag.007.rrd           # a verified copy: diag.007.repaired.rrd

A daemon stopped by SIGKILL (or a crash, or a power cut) leaves the segment it
was writing without a footer: ``rerun rrd verify`` fails on it ("Missing RRD
footer"), though the viewer still reads its complete chunks.  ``--repair`` reads
every complete chunk of such a file and writes a copy that ``rerun rrd verify``
passes, saying how many chunks it recovered.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys

from streamid.errors import ConfigError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "view",
        help="open .rrd diagnostics (every segment) in the Rerun viewer, render them to PNG, or repair them",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("files", nargs="+", metavar="FILE.rrd",
                   help="recordings to show; FILE.rrd brings its segments FILE.001.rrd, FILE.002.rrd... along")
    p.add_argument("--screenshot", metavar="PNG",
                   help="render the files with the real viewer, headless, into PNG instead of opening a window "
                        "(without a GPU: apt-get install mesa-vulkan-drivers)")
    p.add_argument("--window-size", default="1280x800", metavar="WxH", help="size of the screenshot (default 1280x800)")
    p.add_argument("--timeout", type=float, default=90.0, metavar="S",
                   help="give up the screenshot or the repair after S seconds (default 90)")
    p.add_argument("--repair", action="store_true",
                   help="write a verified copy of each FILE.rrd (exactly the files named) holding every complete chunk")
    p.add_argument("-o", "--output", metavar="OUT.rrd",
                   help="with --repair and one file: where the copy goes (default FILE.repaired.rrd beside it)")
    p.add_argument("--print-command", action="store_true",
                   help="print the viewer command that opens the files, and exit")
    p.add_argument("--json", action="store_true", help="one JSON line on stdout instead of text")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from streamid.viz import rrd_files

    if args.output is not None and not args.repair:
        raise ConfigError(f"-o {args.output!r} goes with --repair (it names the repaired copy)")
    if args.repair:
        if args.screenshot or args.print_command:
            raise ConfigError("--repair writes copies; give --screenshot or --print-command in a separate run")
        return _repair(args)
    if not args.timeout > 0:
        raise ConfigError(f"--timeout must be a number of seconds > 0; got {args.timeout}")
    files, empty = rrd_files.resolve(args.files)
    open_ = [str(f) for f in files if not rrd_files.has_footer(f)]
    if not args.json:
        for f in empty:
            print(f"streamid view: {f} is empty (its writer was killed as it created it); left out", file=sys.stderr)
        total = sum(f.stat().st_size for f in files)
        print(f"streamid view: {len(files)} file{'s' if len(files) > 1 else ''} ({total / 1e6:.1f} MB): "
              f"{', '.join(f.name for f in files[:3])}{' ...' if len(files) > 3 else ''}", file=sys.stderr)
        for name in open_:
            print(f"streamid view: {name} has no footer (its writer was killed, or is still writing it); the viewer "
                  f"reads its complete chunks, `streamid view --repair {shlex.quote(name)}` writes a verified copy",
                  file=sys.stderr)
    from streamid.viz.screenshot import rerun_cli

    # The viewer lays the recording out by the blueprint of the file it opens first. The daemon's layout only grows
    # (a stream's tab when it is declared, an output's tab when its first model comes), so the newest segment holds
    # the fullest one: opened oldest first, a stream of several outputs showed the viewer's default layout, its first
    # segment's blueprint holding no tab yet (seen with the F-16 log).
    newest_first = list(reversed(files))
    command = [rerun_cli(), "--bind", "127.0.0.1", *map(str, newest_first)]
    doc: dict[str, object] = {"files": [str(f) for f in files], "no_footer": open_, "empty": [str(f) for f in empty]}
    if args.print_command:
        _say(args, {**doc, "command": command}, shlex.join(command))
        return 0
    if args.screenshot:
        from streamid.viz.rerun_view import screenshot

        try:
            png = screenshot(newest_first, args.screenshot, window_size=args.window_size, timeout_s=args.timeout)
        except (OSError, RuntimeError) as exc:
            print(f"streamid view: error: {exc}", file=sys.stderr)
            return 1
        _say(args, {**doc, "screenshot": str(png)}, f"screenshot: {png}")
        return 0
    return subprocess.run(command, check=False).returncode


def _repair(args: argparse.Namespace) -> int:
    from streamid.viz import rrd_files
    from streamid.viz.rerun_view import repair_rrd

    if args.output is not None and len(args.files) != 1:
        raise ConfigError(f"-o names the copy of one file; got {len(args.files)} files ({', '.join(args.files)})")
    for f in args.files:
        rrd_files.check_rrd(f)  # every name checked before anything is written
    reports = []
    for f in args.files:
        try:
            rep = repair_rrd(f, args.output, timeout_s=args.timeout)
        except RuntimeError as exc:
            print(f"streamid view: error: {exc}", file=sys.stderr)
            return 1
        reports.append(rep)
        if not args.json:
            print(f"repaired {rep}")
    if args.json:
        print(json.dumps({"repaired": [{"source": str(r.source), "output": str(r.output), "chunks": r.chunks,
                                        "source_had_footer": r.source_had_footer, "source_bytes": r.source_bytes,
                                        "output_bytes": r.output_bytes} for r in reports]}))
    return 0


def _say(args: argparse.Namespace, doc: dict[str, object], text: str) -> None:
    print(json.dumps(doc) if args.json else text)
