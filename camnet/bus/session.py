"""Opening the Zenoh session of a node from shared command-line flags.

Default (no --connect/--listen/--zenoh-config): peer mode with multicast
scouting off and a loopback rendezvous. Every node tries to listen on
``tcp/127.0.0.1:7447`` (the first one gets it), also listens on an ephemeral
loopback port, and connects to ``tcp/127.0.0.1:7447``, retrying. Zenoh's
gossip then tells every peer about the others, so nodes on one machine find
each other with no router and no multicast; when the node holding the port
exits, the next one to start takes it over and the rest reconnect to it. A
router on 7447 (`camnet router` or zenohd) plays the same role.

Nothing listens beyond loopback unless told to: a node given only --connect
listens on an ephemeral loopback port, and one told to listen on another
address without TLS warns, since anyone who reaches that port reads every
frame and may publish. Across hosts a rig is secured with --secure DIR (from
`camnet secure init`, camnet.bus.security): every node is then a TLS client
of the router with its own certificate, and the router's access control
decides who may say what.

Multicast scouting (--scouting) also works on loopback on Linux, but it is
off by default: it leaks across hosts on a LAN and is often blocked in
containers. Flags given on the command line replace the defaults and are
applied over a --zenoh-config file; a mode set in that file is kept.

Every session logs losing its router and getting it back (Zenoh reconnects
by itself), so that an outage shows in the nodes' logs.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import json
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass

log = logging.getLogger(__name__)

RENDEZVOUS_ENDPOINT = "tcp/127.0.0.1:7447"
EPHEMERAL_LOOPBACK_ENDPOINT = "tcp/127.0.0.1:0"
# Links that are encrypted, or that never leave the host.
_PRIVATE_PROTOCOLS = frozenset({"tls", "quic", "unixsock-stream", "unixpipe", "vsock"})


@dataclass(frozen=True)
class BusOptions:
    """How a node joins the bus. Empty endpoint lists mean the loopback rendezvous.

    `secure` is a directory from `camnet secure init`; the node then joins as
    `identity` (its node kind, camnet.bus.security.IDENTITIES).
    """

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    zenoh_config: str | None = None
    scouting: bool = False
    mode: str = "peer"
    secure: str | None = None
    identity: str | None = None
    session_id: str | None = None  # the Zenoh session id to take (camnet.bus.source); None: a random one


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh flags shared by every node command."""
    group = parser.add_argument_group("bus (Zenoh)")
    group.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                       help="connect to this Zenoh endpoint, e.g. tcp/10.0.0.5:7447 (repeatable)")
    group.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                       help="listen on this Zenoh endpoint (repeatable; default with --connect: "
                            "loopback only)")
    group.add_argument("--secure", metavar="DIR",
                       help="join a secured rig: TLS to its router with this node's certificate from "
                            "DIR, written by `camnet secure init` (docs/security.md)")
    group.add_argument("--zenoh-config", metavar="FILE.json5",
                       help="Zenoh configuration file; the flags above override it")
    group.add_argument("--scouting", action=argparse.BooleanOptionalAction, default=False,
                       help="multicast scouting (default: off; loopback rendezvous instead)")


def options_from_args(args: argparse.Namespace, *, mode: str = "peer") -> BusOptions:
    """The bus options of a parsed command line; with --secure, the command's identity."""
    from camnet.bus.security import COMMAND_IDENTITY

    secure = getattr(args, "secure", None)
    return BusOptions(connect=tuple(args.connect), listen=tuple(args.listen),
                      zenoh_config=args.zenoh_config, scouting=args.scouting, mode=mode, secure=secure,
                      identity=COMMAND_IDENTITY.get(getattr(args, "command", None) or "") if secure else None)


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
    if options.session_id:
        _insert(config, "id", options.session_id)
    if options.secure:
        _apply_secure(config, options)
        return config
    if json.loads(config.get_json("mode")) is None:
        # A mode written in the file wins, e.g. "client" for nodes that may reach the rig
        # only through its router.
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
        return config
    mode = json.loads(config.get_json("mode"))
    if mode != "client" and config.get_json("listen/endpoints") == zenoh.Config().get_json("listen/endpoints"):
        # Zenoh's own default listens on every interface: loopback unless told otherwise.
        _insert(config, "listen/endpoints",
                [RENDEZVOUS_ENDPOINT if mode == "router" else EPHEMERAL_LOOPBACK_ENDPOINT])
    if options.connect:
        # A router that is not up yet must not stop the node: keep retrying.
        _insert(config, "connect/exit_on_failure", False)
    _warn_if_exposed(config)
    return config


def _apply_secure(config, options: BusOptions) -> None:
    from camnet.bus.security import ROUTER, load_secure_dir, zenoh_settings
    from camnet.errors import InputError

    if options.identity is None:
        raise InputError("--secure: this command has no identity on a secured rig")
    secure = load_secure_dir(options.secure, options.identity)
    settings = zenoh_settings(secure, options.identity, connect=options.connect, listen=options.listen)
    for key, value in settings.items():
        _insert(config, key, value)
    if options.identity != ROUTER:
        log.info("secured rig %r: joining as the %s through %s", secure.rig, options.identity,
                 ", ".join(settings["connect/endpoints"]))


def listen_endpoints(config) -> list[str]:
    """The endpoints a session of `config` will listen on (Zenoh's defaults by mode included)."""
    value = json.loads(config.get_json("listen/endpoints"))
    if isinstance(value, dict):
        value = value.get(json.loads(config.get_json("mode")) or "peer") or []
    return list(value)


def exposed(endpoint: str) -> bool:
    """Whether listening on `endpoint` lets other hosts in without TLS."""
    protocol, _, address = endpoint.partition("/")
    if protocol in _PRIVATE_PROTOCOLS:
        return False
    host = address.split("#", 1)[0].split("?", 1)[0].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return False
    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:
        return True  # a host name: it may resolve to any interface


def _warn_if_exposed(config) -> None:
    for endpoint in listen_endpoints(config):
        if exposed(endpoint):
            log.warning("LISTENING ON %s WITHOUT TLS: anyone who can reach this port sees every frame and "
                        "can publish forged observations and calibrations. Secure the rig (camnet secure "
                        "init, then --secure DIR; docs/security.md) or listen on 127.0.0.1", endpoint)


def _insert(config, key: str, value) -> None:
    import zenoh

    from camnet.errors import InputError

    try:
        config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise InputError(f"Zenoh option {key}={value!r} refused: {exc}") from exc


def open_session(options: BusOptions, *, config=None):
    """An open zenoh.Session; use it as a context manager. `config`: `make_config(options)`, if made.

    A client (every node of a secured rig) cannot open without its router:
    it waits for one, saying so every try.
    """
    import zenoh

    from camnet.errors import CamnetError

    config = make_config(options) if config is None else config
    client = json.loads(config.get_json("mode")) == "client"
    while True:
        try:
            session = zenoh.open(config)
            break
        except zenoh.ZError as exc:
            if not client:
                raise CamnetError(f"cannot open the Zenoh session ({options}): {exc}; check the "
                                  "--connect/--listen endpoints (a port may be in use)") from exc
            log.warning("no router answers at %s yet (%s); trying again",
                        ", ".join(json.loads(config.get_json("connect/endpoints"))), exc)
            time.sleep(1.0)
    log.debug("zenoh session %s open", session.info.zid())
    watch_routers(session)
    return session


def watch_routers(session) -> None:
    """Log losing a router and getting it back, for as long as `session` is open."""
    import zenoh

    lost_at: dict[str, float] = {}

    def on_event(event) -> None:
        transport = event.transport
        if transport.whatami != zenoh.WhatAmI.ROUTER:
            return
        zid = str(transport.zid)
        if event.kind == zenoh.SampleKind.DELETE:
            lost_at["since"] = time.monotonic()
            log.warning("lost the router %s: nothing reaches this node until it is back "
                        "(Zenoh reconnects by itself)", zid)
        elif "since" in lost_at:
            log.warning("router %s reached again after %.1f s without one", zid,
                        time.monotonic() - lost_at.pop("since"))
        else:
            log.info("connected to the router %s", zid)

    # A callback listener lives as long as the session: no handle to keep.
    session.info.declare_transport_events_listener(on_event, history=False)


@contextlib.contextmanager
def joined(options: BusOptions, *, config=None) -> Iterator:
    """`open_session` for the block, closed after it by `close_session`: a node or command whose
    work is done never ends in a traceback because Zenoh was slow to close."""
    session = open_session(options, config=config)
    try:
        yield session
    finally:
        close_session(session)


def close_session(session) -> None:
    """Close `session`. A close that fails (Zenoh gives up after some 10 s on a slow or lossy link,
    raising "close operation timed out") is logged, not raised: the work is done and the process
    is leaving."""
    import zenoh

    try:
        session.close()
    except zenoh.ZError as exc:
        log.warning("the Zenoh session did not close cleanly (%s); leaving anyway", exc)


def declare_liveliness(session, key: str):
    """Declare a liveliness token at `key`; undeclare it (or close the session) to leave."""
    return session.liveliness().declare_token(key)
