"""camnet fuse SITE_A.json SITE_B.json --layout facing:2.0m -o meeting.json"""

from __future__ import annotations

import argparse

LAYOUT_HELP = "facing:DISTANCE (metres, e.g. facing:2.0m): each site's front toward the other's, that far apart"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.viz_sinks import add_rerun_arguments

    parser.add_argument("calibrations", nargs=2, metavar="SITE.json",
                        help="each site's camnet.calibration/1 file, written in its floor frame (a rig with world: "
                             "floor)")
    parser.add_argument("--layout", required=True, metavar="facing:DISTANCE", help=LAYOUT_HELP)
    parser.add_argument("--names", metavar="A,B", help="the sites' names (default: the files' names without .json)")
    parser.add_argument("-o", "--output", required=True, help="the camnet.meeting/1 file to write")
    add_rerun_arguments(parser)


def parse_layout(text: str):
    """The layout of a ``--layout`` value ("facing:2.0m", "facing:2"); a bad one is an InputError naming it."""
    from camnet.errors import InputError
    from camnet.model.meeting import LAYOUTS, Layout

    kind, _, distance = text.partition(":")
    if kind not in LAYOUTS or not distance:
        raise InputError(f"--layout {text}: expected {LAYOUT_HELP}")
    number = distance[:-1] if distance.endswith("m") else distance
    try:
        distance_m = float(number)
    except ValueError:
        raise InputError(f"--layout {text}: {distance!r} is not a distance in metres, e.g. facing:2.0m") from None
    if not 0.0 < distance_m < 1e4:
        raise InputError(f"--layout {text}: the distance must be positive and under 10 km, got {distance_m:g} m")
    return Layout(kind, distance_m)


def site_calibration(path: str):
    """The calibration of one site's file, refused in one line where it has no floor to stand on."""
    from camnet.errors import InputError
    from camnet.io.formats import load_json, parse_calibration

    try:
        cal = parse_calibration(load_json(path))
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    if cal.floor_frame is None:
        raise InputError(f"{path}: written in the left camera's frame, not a floor's: calibrate the site with "
                         "`world: floor` in its rig file, so that its floor can be set on the other's")
    if not cal.floor_frame.found:
        raise InputError(f"{path}: its scene showed no floor ({cal.floor_frame.reason}), so its height above the "
                         "shared floor is unknown: calibrate it again with the floor in view")
    return cal


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    from pathlib import Path

    from camnet import viz
    from camnet.errors import InputError
    from camnet.io.atomic import write_text_atomic
    from camnet.io.meeting import Meeting, Site, meeting_to_doc
    from camnet.model.meeting import placements
    from camnet.viz_sinks import sinks_from_args

    layout = parse_layout(args.layout)
    names = args.names.split(",") if args.names else [Path(p).name.removesuffix(".json") for p in args.calibrations]
    if len(names) != 2 or len(set(names)) != 2 or not all(names):
        raise InputError(f"--names {args.names or ','.join(names)}: two different names are needed, e.g. "
                         "--names a,b")
    sinks = sinks_from_args(args)
    calibrations = [site_calibration(p) for p in args.calibrations]
    meeting = Meeting(layout, tuple(Site(n, c, p) for n, c, p in zip(names, calibrations, placements(layout, 2),
                                                                      strict=True)))
    doc = json.dumps(meeting_to_doc(meeting))
    rec = viz.open_recording(rig="meeting", sinks=sinks)  # a sink that cannot open leaves nothing written
    try:
        written = write_text_atomic(args.output, doc)
        viz.log_meeting(rec, meeting)
    finally:
        viz.close_recording(rec)
    print(json.dumps({"output": str(written), "sites": names, "layout": args.layout,
                      "cameras": sum(len(c.cameras) for c in calibrations)}), file=sys.stdout)
    return 0
