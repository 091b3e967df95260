"""``streamid router``: a Zenoh router for deployments that outgrow one machine.

Eclipse Zenoh's own router (``zenohd``) is not on PyPI; any Zenoh session opened
in router mode is a working router, so streamid ships one.  Several daemons
(each serving some of the streams), the sample publishers and the model
subscribers then all connect to it::

    streamid router --listen tcp/0.0.0.0:7447          # on the machine everyone reaches
    streamid daemon --connect tcp/ROUTER:7447 --stream piezo
    streamid daemon --connect tcp/ROUTER:7447 --stream mr_damper --stream reactor
    streamid replay piezo_sim_20khz --connect tcp/ROUTER:7447

With ``--zenoh-config`` the router enforces Zenoh authentication and access
control (``examples/zenoh/router.json5``).
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
