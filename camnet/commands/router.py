"""`camnet router`: an embedded Zenoh router, for multi-host rigs and docker."""

from __future__ import annotations

import argparse
import logging
import threading

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus.node import stop_on_signals
    from camnet.bus.session import open_session, options_from_args

    options = options_from_args(args, mode="router")
    with open_session(options) as session, stop_on_signals(threading.Event()) as stop:
        endpoints = ", ".join(options.listen) or "the loopback rendezvous (tcp/127.0.0.1:7447)"
        print(f"camnet router {session.info.zid()} listening on {endpoints}; Ctrl-C to stop",
              flush=True)
        while not stop.wait(1.0):
            pass
        log.info("router stopping")
    return 0
