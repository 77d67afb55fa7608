"""`camnet secure init DIR --rig RIG`: the CA, certificates and keys of a secured rig (docs/security.md)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    init = sub.add_parser("init", help="write a rig's CA, a certificate per node kind, and the router's",
                          description="Write a rig's CA, the router's certificate and one certificate per "
                                      "node kind into DIR (private, 0700). Nodes then join with --secure DIR.")
    init.add_argument("directory", metavar="DIR", help="where to write them (must not exist, unless --force)")
    init.add_argument("--rig", required=True, metavar="RIG.yaml|NAME",
                      help="the rig file, or just the rig's name: the router admits only this rig's keys")
    init.add_argument("--router-host", action="append", default=[], metavar="HOST",
                      help="name or IP address the nodes dial the router by (repeatable; the first is "
                           "the nodes' default; default: localhost, for one machine)")
    init.add_argument("--port", type=int, default=7447, help="the router's TLS port (default 7447)")
    init.add_argument("--force", action="store_true",
                      help="replace an existing DIR (every node and the router then need the new files)")


def run(args: argparse.Namespace) -> int:
    from camnet.bus.certificates import write_rig_secrets
    from camnet.bus.security import CA_CERTIFICATE, CA_PRIVATE_KEY, IDENTITIES, MANIFEST, ROUTER
    from camnet.commands.calibrator import load_rig_arg

    rig, _ = load_rig_arg(args.rig)
    hosts = args.router_host or ["localhost"]
    secure = write_rig_secrets(args.directory, rig=rig, router_hosts=hosts, port=args.port, force=args.force)
    kinds = ", ".join(i for i in IDENTITIES if i != ROUTER)
    print(f"camnet secure: wrote {secure.path} for rig {rig!r}; nodes dial {secure.router_endpoints[0]}")
    print(f"  router host: camnet router --secure {secure.path}   "
          f"(needs {MANIFEST}, {CA_CERTIFICATE}, {ROUTER}.pem, {ROUTER}-key.pem)")
    print(f"  each node:   camnet <command> ... --secure {secure.path}   "
          f"(needs {MANIFEST}, {CA_CERTIFICATE}, KIND.pem, KIND-key.pem; kinds: {kinds})")
    print(f"  keep {CA_PRIVATE_KEY} off the rig: it signs new identities")
    if not args.router_host:
        print("  nodes on other hosts: run again with --force --router-host NAME (the router host's name)")
    return 0
