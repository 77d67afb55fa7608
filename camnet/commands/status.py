"""`camnet status --rig NAME`: the live nodes of a rig, with their frame rates and drops."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    parser.add_argument("--rig", required=True, metavar="NAME", help="rig name (as in its file)")
    parser.add_argument("--wait-s", type=float, default=2.0, metavar="S",
                        help="seconds to listen for node statistics (default: 2)")
    add_bus_arguments(parser)


def format_table(nodes: list[tuple[str, str]], stats: dict) -> str:
    """Rows 'kind id fps dropped frames detail' for live `nodes`, with `stats` by (kind, id);
    the detail ends with what the node counted as faults (malformed messages, failed handlers)."""
    header = f"{'KIND':<12}{'ID':<16}{'FPS':>8}{'DROPPED':>9}{'FRAMES':>9}  DETAIL"
    rows = [header]
    for kind, node_id in sorted(nodes):
        s = stats.get((kind, node_id))
        if s is None:
            rows.append(f"{kind:<12}{node_id:<16}{'-':>8}{'-':>9}{'-':>9}  (no statistics yet)")
        else:
            faults = "".join(f"; {fault} {n}" for fault, n in sorted(s.faults.items()))
            rows.append(f"{kind:<12}{node_id:<16}{s.fps:>8.1f}{s.dropped:>9d}{s.frames:>9d}"
                        f"  {s.detail}{faults}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    import threading
    import time

    from camnet.bus import keys
    from camnet.bus.node import Tally
    from camnet.bus.session import open_session, options_from_args
    from camnet.bus.stats import NodeStats
    from camnet.errors import InputError

    stats: dict[tuple[str, str], NodeStats] = {}
    lock = threading.Lock()
    malformed = Tally(log)

    def on_stats(sample) -> None:
        try:
            s = NodeStats.from_json(bytes(sample.payload.to_bytes()))
        except InputError as exc:
            malformed.count("stats", "ignoring statistics on %s: %s", sample.key_expr, exc)
            return
        with lock:
            stats[(s.kind, s.node_id)] = s

    with open_session(options_from_args(args)) as session:
        subscriber = session.declare_subscriber(keys.all_node_stats(args.rig), on_stats)
        time.sleep(args.wait_s)
        nodes = []
        for reply in session.liveliness().get(keys.all_nodes(args.rig), timeout=2.0):
            if reply.ok is None:
                continue
            try:
                _, kind, node_id = keys.parse_node(str(reply.ok.key_expr))
            except InputError:
                continue
            nodes.append((kind, node_id))
        subscriber.undeclare()
    with lock:
        table = format_table(nodes, dict(stats))
    print(f"rig {args.rig}: {len(nodes)} live node(s)")
    print(table)
    return 0
