"""``streamid router``: a Zenoh router for deployments that outgrow one machine.

Eclipse Zenoh's own router (``zenohd``) is not on PyPI; any Zenoh session opened
in router mode is a working router, so streamid ships one.  Daemons (each serving
some of the streams), sample publishers and model subscribers on other machines
all connect to it and listen nowhere (a process that only connects is a Zenoh
client: everything goes through the router)::

    streamid router --listen tcp/ROUTER:7447                   # on the machine everyone reaches
    streamid daemon --connect tcp/ROUTER:7447 --stream mr_damper --state-dir state
    streamid daemon --connect tcp/ROUTER:7447 --stream piezo --state-dir state
    streamid replay piezo_p885 --stream piezo --connect tcp/ROUTER:7447 --rate 4 --loop
    streamid watch --connect tcp/ROUTER:7447                   # which daemon serves which stream, the models

Across machines, use TLS and access control (the router enforces them; the
README's "More than one machine" shows every machine's command)::

    streamid router --zenoh-config examples/zenoh/tls/router.json5 --listen tls/ROUTER:7447

Only the router's port (TCP 7447 here) needs to be open to the other machines.
"""

from __future__ import annotations

import argparse
import sys
import threading

from streamid.commands.os_signals import stop_on_signals
from streamid.transport import DEFAULT_ENDPOINT, Bus
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "router",
        help="run a Zenoh router that daemons, publishers and subscribers connect to",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_connection_flags(p, default_listen=(DEFAULT_ENDPOINT,), default_mode="router")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: never)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    stop = threading.Event()
    with stop_on_signals(stop), Bus(settings):
        where = ", ".join(settings.listen) or "the --zenoh-config file's endpoints"
        print(f"streamid router: {settings.mode or 'configured'} mode, listening on {where}; Ctrl-C stops",
              file=sys.stderr, flush=True)
        stop.wait(args.duration)
    return 0
