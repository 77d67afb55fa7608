"""`camnet driver sim|aravis|v4l2`: publish one camera's frames on the bus."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.frame import Compression
    from camnet.bus.session import add_bus_arguments
    from camnet.io.rig import DRIVERS

    parser.add_argument("driver", choices=DRIVERS, help="camera driver")
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file")
    parser.add_argument("--camera", required=True, metavar="ID", help="camera id in the rig")
    parser.add_argument("--compression", choices=[c.name.lower() for c in Compression], default="none",
                        help="frame compression on the wire (default: none)")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N",
                        help="stop after N frames (default: run until stopped)")
    parser.add_argument("--stats-period-s", type=float, default=1.0, metavar="S",
                        help="seconds between statistics messages (default: 1)")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus.frame import Compression
    from camnet.bus.session import open_session, options_from_args
    from camnet.drivers.base import create_camera
    from camnet.errors import InputError
    from camnet.io.rig import load_rig

    rig = load_rig(args.rig)
    entry = rig.camera(args.camera)
    if entry.driver != args.driver:
        raise InputError(f"{args.rig}: camera {entry.id!r} uses driver {entry.driver!r}, "
                         f"not {args.driver!r}")
    camera = create_camera(entry, rig)
    with open_session(options_from_args(args)) as session:
        from camnet.drivers.node import DriverNode

        node = DriverNode(session, rig, camera, compression=Compression[args.compression.upper()],
                          stats_period_s=args.stats_period_s)
        return node.run(max_frames=args.max_frames)
