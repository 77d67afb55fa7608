"""`camnet features --rig RIG.yaml --camera ID`: one camera's feature stage as a node of its own."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file")
    parser.add_argument("--camera", required=True, metavar="ID", help="camera id in the rig")
    parser.add_argument("--period-s", type=float, default=0.25, metavar="S",
                        help="detect at capture times on this grid (default: 0.25)")
    parser.add_argument("--detector", choices=["sift", "orb"], default="sift",
                        help="the detector; the matcher must use the same (default: sift)")
    parser.add_argument("--stats-period-s", type=float, default=1.0, metavar="S",
                        help="seconds between statistics messages (default: 1)")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus.session import open_session, options_from_args
    from camnet.errors import InputError
    from camnet.io.rig import load_rig
    from camnet.matching.features import Detector, MatcherConfig
    from camnet.services.features import FeatureNode, FeatureStageConfig

    rig = load_rig(args.rig)
    camera_id = rig.camera(args.camera).id  # InputError for a camera not in the rig
    if not args.period_s > 0:
        raise InputError(f"--period-s: must be positive, got {args.period_s}")
    config = FeatureStageConfig(period_s=args.period_s, matcher=MatcherConfig(detector=Detector(args.detector)))
    with open_session(options_from_args(args)) as session:
        return FeatureNode(session, rig.name, camera_id, config, stats_period_s=args.stats_period_s).run()
