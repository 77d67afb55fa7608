"""`camnet driver sim|aravis|v4l2`: publish a camera's frames on the bus.

`--camera` repeated runs several cameras of the rig in one process, as one
camera host does: one Zenoh session, a driver (and with `--features` its
feature stage) per camera, each on its own thread.
"""

from __future__ import annotations

import argparse
import contextlib
import logging

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.frame import Compression
    from camnet.bus.session import add_bus_arguments
    from camnet.io.rig import DRIVERS

    parser.add_argument("driver", choices=DRIVERS, help="camera driver")
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file")
    parser.add_argument("--camera", required=True, action="append", metavar="ID",
                        help="camera id in the rig; repeat it to run several cameras of the rig in this "
                             "process (one session, a thread per camera)")
    parser.add_argument("--files-start-ns", type=int, metavar="NS",
                        help="v4l2 only: when frame 0 of the video files and image sequences without a timestamps "
                             "file is due, in ns since the Unix epoch; frame i is stamped and published at NS + "
                             "i/fps, and a driver that opens later begins at the frame then due. camnet up gives "
                             "every v4l2 driver it starts the same, so that the rig's files play in step "
                             "(default: the driver's own start)")
    parser.add_argument("--compression", choices=[c.name.lower() for c in Compression], default="none",
                        help="frame compression on the wire (default: none)")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N",
                        help="stop after N frames of each camera (default: run until stopped)")
    parser.add_argument("--stats-period-s", type=float, default=1.0, metavar="S",
                        help="seconds between statistics messages (default: 1)")
    parser.add_argument("--features", action="store_true",
                        help="also detect features here, on the camera's host, and publish them on "
                             "camnet/<rig>/cam/<id>/features (the matcher then only matches)")
    parser.add_argument("--features-period-s", type=float, default=0.25, metavar="S",
                        help="with --features: detect at capture times on this grid (default: 0.25)")
    parser.add_argument("--features-pace", action=argparse.BooleanOptionalAction, default=True,
                        help="with --features: detect only on every 2**k-th grid point, the k that offers the "
                             "matcher at most twice the frame sets it matches a second (default: on)")
    parser.add_argument("--detector", choices=["sift", "orb"], default="sift",
                        help="with --features: the detector; the matcher must use the same (default: sift)")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus.frame import Compression
    from camnet.bus.session import joined, options_from_args
    from camnet.drivers.base import create_camera
    from camnet.errors import InputError
    from camnet.io.rig import load_rig

    rig = load_rig(args.rig)
    if len(set(args.camera)) < len(args.camera):
        raise InputError(f"--camera: a camera given twice ({', '.join(args.camera)})")
    entries = [rig.camera(camera_id) for camera_id in args.camera]
    for entry in entries:
        if entry.driver != args.driver:
            raise InputError(f"{args.rig}: camera {entry.id!r} uses driver {entry.driver!r}, "
                             f"not {args.driver!r}")
    options = {}
    if args.files_start_ns is not None:
        if args.driver != "v4l2":
            raise InputError(f"--files-start-ns: only the v4l2 driver plays files, not {args.driver!r}; leave it out")
        options["files_start_ns"] = args.files_start_ns
    cameras = [create_camera(entry, rig, **options) for entry in entries]
    with joined(options_from_args(args)) as session:
        from camnet.drivers.node import DriverNode, run_together

        with contextlib.ExitStack() as stack:
            pace = _matcher_pace(session, rig.name, args, stack) if args.features and args.features_pace else None
            nodes = []
            for camera in cameras:
                on_frame = _feature_worker(session, rig.name, camera.camera_id, args, pace, stack).offer \
                    if args.features else None
                nodes.append(DriverNode(session, rig, camera, compression=Compression[args.compression.upper()],
                                        stats_period_s=args.stats_period_s, on_frame=on_frame))
            if len(nodes) == 1:
                return nodes[0].run(max_frames=args.max_frames)
            return run_together(nodes, max_frames=args.max_frames)


def _matcher_pace(session, rig_name: str, args: argparse.Namespace, stack: contextlib.ExitStack):
    """One pace for the feature stages of this process, from the matcher's statistics."""
    from camnet.bus import keys
    from camnet.bus.node import Tally, guarded
    from camnet.services.features import MatcherPace

    pace = MatcherPace(args.features_period_s)
    subscriber = session.declare_subscriber(keys.node_stats(rig_name, "matcher", "matcher"),
                                            guarded(pace.on_sample, Tally(log), "reading the matcher's statistics"))
    stack.callback(subscriber.undeclare)
    return pace


def _feature_worker(session, rig_name: str, camera_id: str, args: argparse.Namespace, pace,
                    stack: contextlib.ExitStack):
    """The feature stage of the camera, publishing beside its driver, declared and running until `stack` closes."""
    import zenoh

    from camnet.bus import keys
    from camnet.bus.source import SourcedPublisher, declare_stage
    from camnet.matching.features import Detector, MatcherConfig
    from camnet.services.features import FeatureStageConfig, FeatureWorker

    # DROP, as frames: a slow link loses a frame set's features rather than stalling detection.
    # Stating its session as the source: the matcher takes the camera's features from this stage only.
    publisher = SourcedPublisher(session.declare_publisher(keys.features(rig_name, camera_id),
                                                           congestion_control=zenoh.CongestionControl.DROP))
    config = FeatureStageConfig(period_s=args.features_period_s,
                                matcher=MatcherConfig(detector=Detector(args.detector)))
    stack.callback(declare_stage(session, rig_name, camera_id).undeclare)
    return stack.enter_context(FeatureWorker(publisher, camera_id, config, pace=pace))
