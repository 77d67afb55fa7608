"""Opening the Zenoh session of a node from shared command-line flags.

Default (no --connect/--listen/--zenoh-config): peer mode with multicast
scouting off and a loopback rendezvous. Every node tries to listen on
``tcp/127.0.0.1:7447`` (the first one gets it), also listens on an ephemeral
loopback port, and connects to ``tcp/127.0.0.1:7447``, retrying. Zenoh's
gossip then tells every peer about the others, so nodes on one machine find
each other with no router and no multicast; when the node holding the port
exits, the next one to start takes it over and the rest reconnect to it. A
router on 7447 (`camnet router` or zenohd) plays the same role.

Multicast scouting (--scouting) also works on loopback on Linux, but it is
off by default: it leaks across hosts on a LAN and is often blocked in
containers. Flags given on the command line replace the defaults and are
applied over a --zenoh-config file; a mode set in that file is kept.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass

log = logging.getLogger(__name__)

RENDEZVOUS_ENDPOINT = "tcp/127.0.0.1:7447"
EPHEMERAL_LOOPBACK_ENDPOINT = "tcp/127.0.0.1:0"


@dataclass(frozen=True)
class BusOptions:
    """How a node joins the bus. Empty endpoint lists mean the loopback rendezvous."""

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    zenoh_config: str | None = None
    scouting: bool = False
    mode: str = "peer"


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh flags shared by every node command."""
    group = parser.add_argument_group("bus (Zenoh)")
    group.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                       help="connect to this Zenoh endpoint, e.g. tcp/10.0.0.5:7447 (repeatable)")
    group.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                       help="listen on this Zenoh endpoint (repeatable)")
    group.add_argument("--zenoh-config", metavar="FILE.json5",
                       help="Zenoh configuration file; the flags above override it")
    group.add_argument("--scouting", action=argparse.BooleanOptionalAction, default=False,
                       help="multicast scouting (default: off; loopback rendezvous instead)")


def options_from_args(args: argparse.Namespace, *, mode: str = "peer") -> BusOptions:
    return BusOptions(connect=tuple(args.connect), listen=tuple(args.listen),
                      zenoh_config=args.zenoh_config, scouting=args.scouting, mode=mode)


def make_config(options: BusOptions):
    """The zenoh.Config for `options`."""
    import zenoh

    from camnet.errors import InputError

    if options.zenoh_config:
        try:
            config = zenoh.Config.from_file(options.zenoh_config)
        except (OSError, zenoh.ZError) as exc:
            raise InputError(f"{options.zenoh_config}: cannot load Zenoh config: {exc}") from exc
    else:
        config = zenoh.Config()
    if json.loads(config.get_json("mode")) is None:
        # A mode written in the file wins, e.g. "client" for nodes that may reach the rig
        # only through its router (docker/zenoh/node.json5).
        _insert(config, "mode", options.mode)
    _insert(config, "scouting/multicast/enabled", options.scouting)
    explicit = bool(options.connect or options.listen or options.zenoh_config)
    if options.connect:
        _insert(config, "connect/endpoints", list(options.connect))
    if options.listen:
        _insert(config, "listen/endpoints", list(options.listen))
    if not explicit:
        if options.mode == "router":
            # A router exists to hold the rendezvous: failing to listen is an error.
            _insert(config, "listen/endpoints", [RENDEZVOUS_ENDPOINT])
        else:
            _insert(config, "listen/endpoints",
                    [RENDEZVOUS_ENDPOINT, EPHEMERAL_LOOPBACK_ENDPOINT])
            # Only one node can own the rendezvous port: the others must not fail on it.
            _insert(config, "listen/exit_on_failure", False)
            _insert(config, "connect/endpoints", [RENDEZVOUS_ENDPOINT])
            _insert(config, "connect/exit_on_failure", False)
    elif options.connect:
        # A router that is not up yet must not stop the node: keep retrying.
        _insert(config, "connect/exit_on_failure", False)
    return config


def _insert(config, key: str, value) -> None:
    import zenoh

    from camnet.errors import InputError

    try:
        config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise InputError(f"Zenoh option {key}={value!r} refused: {exc}") from exc


def open_session(options: BusOptions):
    """An open zenoh.Session; use it as a context manager."""
    import zenoh

    from camnet.errors import CamnetError

    config = make_config(options)
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        raise CamnetError(f"cannot open the Zenoh session ({options}): {exc}; check the "
                          "--connect/--listen endpoints (a port may be in use)") from exc
    log.debug("zenoh session %s open", session.info.zid())
    return session


def declare_liveliness(session, key: str):
    """Declare a liveliness token at `key`; undeclare it (or close the session) to leave."""
    return session.liveliness().declare_token(key)
