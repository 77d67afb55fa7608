"""`camnet status --rig NAME`: the live nodes of a rig, with their frame rates and drops.

Statistics are listened for `--wait-s`; a live node not heard from by then is
waited for up to LATE_STATS_S longer (on a loaded machine a node's statistics,
one a second, can arrive seconds late, and a node busy with a long solve sends
them late), so that "(no statistics yet)" means a node that says nothing.
Below the table: the cameras as the matcher receives them (a camera silent
for longer than a frame set waits is MISSING, with the seconds since its
last frame), and what looks wrong. Statistics are what a node says of
itself, and any peer may publish them: those of a node with no liveliness
token, and a camera's rate that the matcher does not receive, are flagged, as
are features of a camera that the matcher ignored, from another publisher than
the camera's feature stage, and calibrations a node ignored, from another
publisher than the rig's calibrator.
"""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    parser.add_argument("--rig", required=True, metavar="NAME", help="rig name (as in its file)")
    parser.add_argument("--wait-s", type=float, default=2.0, metavar="S",
                        help="seconds to listen for node statistics (default: 2); a live node not heard "
                             f"from by then is waited for up to {LATE_STATS_S:.0f} s more")
    add_bus_arguments(parser)


# On a loaded machine a node's statistics, published every second, can arrive seconds apart: wait long enough
# for a live node not to look silent (docs/benchmarks.md, "Evidence behind the nodes' choices").
LATE_STATS_S = 10.0


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


# A driver may claim this much more than the matcher receives of it (the matcher drops late frames
# only after receiving them, so the two rates agree on a healthy rig) before it is flagged.
RATE_MISMATCH_FACTOR = 1.5
RATE_MISMATCH_FPS = 2.0


def format_cameras(stats: dict) -> list[str]:
    """Lines for the cameras as the matcher receives them (none when no matcher reports)."""
    lines = []
    for (kind, _), s in sorted(stats.items()):
        if kind != "matcher" or not s.cameras:
            continue
        lines.append("cameras as the matcher receives them:")
        for camera_id, seen in s.cameras.items():
            age = "no frame yet" if seen.age_s is None else f"last frame {seen.age_s:.1f} s ago"
            state = "MISSING" if seen.missing else "ok"
            lines.append(f"  {camera_id:<16}{state:<9}{seen.fps:>7.1f} fps  {age}")
    return lines


FOREIGN_FEATURES = "foreign features: "  # the matcher's count of them, by camera (services/matcher.py)


def suspicious(nodes: list[tuple[str, str]], stats: dict) -> list[str]:
    """What in `stats` (by (kind, id)) is not to be believed: statistics of a node with no liveliness
    token among `nodes`, a driver that claims a rate the matcher does not receive or a camera the
    matcher does not know; features of a camera that the matcher ignored, from another publisher
    than the camera's stage; and calibrations a node ignored, from another publisher than the calibrator."""
    from camnet.bus.source import FOREIGN_CALIBRATIONS

    live = set(nodes)
    received = {camera_id: seen for (kind, _), s in stats.items() if kind == "matcher"
                for camera_id, seen in s.cameras.items()}
    found = []
    for (kind, node_id), s in sorted(stats.items()):
        if (kind, node_id) not in live:
            found.append(f"{kind} {node_id}: statistics without a liveliness token (a node gone, or a peer "
                         "publishing in its name)")
        if s.faults.get(FOREIGN_CALIBRATIONS):
            found.append(f"{kind} {node_id}: {s.faults[FOREIGN_CALIBRATIONS]} calibrations from another publisher "
                         "than the rig's calibrator, ignored (the node's log names the publisher)")
        if kind == "matcher":
            found += [f"camera {fault.removeprefix(FOREIGN_FEATURES)}: {n} features from another publisher than its "
                      "feature stage, ignored by the matcher (the matcher's log names the publisher)"
                      for fault, n in sorted(s.faults.items()) if fault.startswith(FOREIGN_FEATURES)]
        if kind != "driver" or not received:
            continue
        seen = received.get(node_id)
        if seen is None:
            found.append(f"driver {node_id}: claims {s.fps:.1f} fps, but the matcher knows no camera {node_id!r}")
        elif s.fps > RATE_MISMATCH_FACTOR * seen.fps + RATE_MISMATCH_FPS:
            found.append(f"driver {node_id}: claims {s.fps:.1f} fps, the matcher receives {seen.fps:.1f} fps")
    return found


class StatsReader:
    """Subscriber callback keeping the latest statistics of each node, by (kind, id); what is no
    statistics message is counted and logged once, never kept."""

    def __init__(self) -> None:
        import threading

        from camnet.bus.node import Tally

        self._arrived = threading.Condition()
        self._stats: dict = {}
        self.malformed = Tally(log)

    def __call__(self, sample) -> None:
        from camnet.bus.stats import NodeStats
        from camnet.errors import InputError

        try:
            s = NodeStats.from_json(bytes(sample.payload.to_bytes()))
        except InputError as exc:
            self.malformed.count("stats", "ignoring statistics on %s: %s", sample.key_expr, exc)
            return
        with self._arrived:
            self._stats[(s.kind, s.node_id)] = s
            self._arrived.notify_all()

    @property
    def stats(self) -> dict:
        with self._arrived:
            return dict(self._stats)

    def wait_for(self, nodes: set[tuple[str, str]], timeout_s: float) -> bool:
        """Whether every one of `nodes` (kind, id) has reported, waiting up to `timeout_s` for them."""
        with self._arrived:
            return self._arrived.wait_for(lambda: nodes <= self._stats.keys(), timeout_s)


def live_nodes(replies) -> list[tuple[str, str, str]]:
    """(rig, kind, id) of the liveliness `replies` that name a node; other keys are skipped."""
    from camnet.bus import keys
    from camnet.errors import InputError

    nodes = []
    for reply in replies:
        if reply.ok is None:
            continue
        try:
            nodes.append(keys.parse_node(str(reply.ok.key_expr)))
        except InputError:
            continue
    return nodes


def rigs_line(rigs: set[str]) -> str:
    return "rigs seen: " + (", ".join(sorted(rigs)) if rigs else "none (is a node running, and on this bus?)")


def report(rig: str, every: list[tuple[str, str, str]], seen: dict) -> int:
    """Print what was seen of `rig`, given the live nodes of `every` rig and the statistics `seen`;
    the exit status: 1 when no node of `rig` is live (a misspelt rig name, or nothing running)."""
    import sys

    nodes = [(kind, node_id) for node_rig, kind, node_id in every if node_rig == rig]
    rigs = {node_rig for node_rig, _, _ in every}
    if not nodes:
        print(f"camnet status: no live node for rig {rig!r}; {rigs_line(rigs)}", file=sys.stderr, flush=True)
        return 1
    print(f"rig {rig}: {len(nodes)} live node(s)")
    print(format_table(nodes, seen))
    for line in format_cameras(seen):
        print(line)
    for line in suspicious(nodes, seen):
        print(f"suspicious: {line}")
    if rigs - {rig}:
        print(f"other {rigs_line(rigs - {rig})}")
    sys.stdout.flush()
    return 0


def run(args: argparse.Namespace) -> int:
    import time

    from camnet.bus import keys
    from camnet.bus.session import joined, options_from_args

    reader = StatsReader()
    with joined(options_from_args(args)) as session:
        subscriber = session.declare_subscriber(keys.all_node_stats(args.rig), reader)
        time.sleep(args.wait_s)
        # The rig's own nodes, and every rig's, asked at once: on a secured rig an observer may see
        # only its own rig's tokens (camnet.bus.security), so the first answer is the one relied on.
        own, every = [session.liveliness().get(selector, timeout=2.0)
                      for selector in (keys.all_nodes(args.rig), keys.every_rigs_nodes())]
        nodes = set(live_nodes(own)) | set(live_nodes(every))
        reader.wait_for({(kind, node_id) for node_rig, kind, node_id in nodes if node_rig == args.rig}, LATE_STATS_S)
        subscriber.undeclare()
        # Printed before the session closes: what was seen is shown even if closing it is slow.
        return report(args.rig, sorted(nodes), reader.stats)
