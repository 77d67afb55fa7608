"""`camnet matcher --rig RIG.yaml`: match a rig's frames and publish pooled observations."""

from __future__ import annotations

import argparse


def _node_flags() -> tuple[tuple[str, dict], ...]:
    """Flags of the node's options; defaults (in the help) are MatcherNodeConfig's, checked by a test."""
    from camnet.matching.features import Detector

    return (
        ("--detector", dict(type=Detector, choices=list(Detector),
                            help="features: sift (accurate) or orb (fast) (default: sift)")),
        ("--sync-tolerance-ms", dict(type=float, metavar="MS",
                                     help="capture times of one frame set differ by at most this (default: 5.0)")),
        ("--sync-free-run", dict(action=argparse.BooleanOptionalAction,
                                 help="the cameras are not triggered together: a frame set takes each camera's "
                                      "frame nearest to the left camera's, within half its frame period, in place "
                                      "of the tolerance (default: False)")),
        ("--max-wait-s", dict(type=float, metavar="S",
                              help="wait this long for late cameras, then match without them; the stereo "
                                   "pair is always required (default: 0.5)")),
        ("--frames-per-camera", dict(type=int, metavar="N",
                                     help="latest frames kept per camera while matching runs (default: 4)")),
        ("--publish-period-s", dict(type=float, metavar="S",
                                    help="at most one observations message per period; 0: one after every "
                                         "frame set that changed the pool (default: 0.0)")),
        ("--max-tracks", dict(type=int, metavar="N", help="tracks kept in the pool (default: 5000)")),
        ("--max-features", dict(type=int, metavar="N", help="features per image (default: 4000)")),
        ("--max-image-side-px", dict(type=int, metavar="PX",
                                     help="detect on a downscaled copy of larger images (default: None, full size)")),
        ("--full-pool-image-side-px", dict(type=int, metavar="PX",
                                           help="once the pool is full, detect on a downscaled copy of larger "
                                                "images: less time per frame set, larger focal errors "
                                                "(default: None, full size; 960 halves a loaded host's latency)")),
        ("--normalise-contrast", dict(action=argparse.BooleanOptionalAction,
                                      help="stretch and equalise (CLAHE) each image before detection, for dark or "
                                           "flat images (default: True)")),
        ("--keyframe-period", dict(type=int, metavar="N",
                                   help="frames detected here (a camera without a feature stage) are detected "
                                        "whole at least every N frames, else only where the image changed since "
                                        "(1: always whole) (default: 30)")),
        ("--view-graph", dict(action=argparse.BooleanOptionalAction,
                              help="once the rig's calibration arrives, match only the pairs whose views overlap, "
                                   "that matched well before, or of a camera new to it; never in lockstep "
                                   "(default: True)")),
        ("--explore-pairs", dict(type=int, metavar="N",
                                 help="with the view graph: also match N other pairs per frame set, in rotation, "
                                      "to find a moved camera again (default: 1)")),
        ("--stats-period-s", dict(type=float, metavar="S",
                                  help="seconds between statistics messages (default: 1.0)")),
        ("--lockstep", dict(action="store_true",
                            help="match the frames of a lockstep replay (camnet replay) one step at a time, on the "
                                 "replayed capture clock, and acknowledge each step (default: False)")),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file (needs a stereo pair)")
    for flag, options in _node_flags():
        # Unset flags stay absent, so the node's own defaults apply.
        parser.add_argument(flag, default=argparse.SUPPRESS, **options)
    add_bus_arguments(parser)


def node_config_from_args(args: argparse.Namespace, rig=None):
    """The MatcherNodeConfig of the flags given, then of the rig file; the rest keep their defaults."""
    from camnet.services.matcher import MatcherNodeConfig, rig_options

    given = {flag[2:].replace("-", "_") for flag, _ in _node_flags()}
    from_rig = rig_options(rig) if rig is not None else {}
    flags = {name: getattr(args, name) for name in given if hasattr(args, name)}
    return MatcherNodeConfig(**{**from_rig, **flags})


def run(args: argparse.Namespace) -> int:
    from camnet.bus.session import joined, options_from_args
    from camnet.io.rig import load_rig
    from camnet.services.matcher import MatcherNode, rig_stereo

    rig = load_rig(args.rig)
    rig_stereo(rig)  # refuse a rig without a stereo pair before joining the bus
    config = node_config_from_args(args, rig)
    with joined(options_from_args(args)) as session:
        return MatcherNode(session, rig, config=config).run()
