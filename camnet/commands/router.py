"""`camnet router`: an embedded Zenoh router, for multi-host rigs and docker.

With --secure DIR it is the router of a secured rig: TLS only, a certificate
demanded of every node, and the rig's access control (camnet.bus.security).
Zenoh's own warnings (a peer refused in the TLS handshake among them) and its
access control's notes go to standard output; RUST_LOG replaces that choice.
Who joins and leaves, by identity, goes to standard error, with or without -v.
"""

from __future__ import annotations

import argparse
import logging
import threading

log = logging.getLogger(__name__)

# Zenoh's warnings, and the access control's note on a peer no subject matches.
ZENOH_LOG = "warn,zenoh::net::routing::interceptor::access_control=info"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    import zenoh

    from camnet.bus.node import stop_on_signals
    from camnet.bus.security import ROUTER, load_secure_dir, watch_identities
    from camnet.bus.session import joined, listen_endpoints, make_config, options_from_args

    if not sys.stdout.isatty():
        os.environ.setdefault("NO_COLOR", "1")  # Zenoh's log lines without colour codes in a log file
    zenoh.init_log_from_env_or(ZENOH_LOG)
    options = options_from_args(args, mode="router")
    config = make_config(options)
    rig = load_secure_dir(options.secure, ROUTER).rig if options.secure else None
    with joined(options, config=config) as session, stop_on_signals(threading.Event()) as stop:
        if rig is not None:
            # Who joins and leaves, by identity, is what the router's log is for (`docker compose
            # logs router`): logged without -v.
            security_log = logging.getLogger("camnet.bus.security")
            if security_log.getEffectiveLevel() > logging.INFO:
                security_log.setLevel(logging.INFO)
            watch_identities(session)
        access = f"; TLS only, access control for rig {rig!r}" if rig is not None else ""
        print(f"camnet router {session.info.zid()} listening on {', '.join(listen_endpoints(config))}{access}; "
              "Ctrl-C to stop", flush=True)
        while not stop.wait(1.0):
            pass
        log.info("router stopping")
    return 0
