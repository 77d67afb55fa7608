"""camnet export CALIBRATION.json --to opencv|colmap|colmap-bin|ros|kalibr|anipose|ply -o OUT"""

from __future__ import annotations

import argparse

FORMATS_HELP = (
    "opencv: FileStorage YAML (one file); colmap: text model (directory); colmap-bin: binary model (directory); "
    "ros: camera_info YAML per camera (directory); kalibr: camchain YAML (one file); "
    "anipose: aniposelib calibration.toml for anipose, FreeMoCap, Pose2Sim (one file); "
    "ply: the points with their sigmas (one file)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", help="a camnet.calibration/1 JSON file")
    parser.add_argument(
        "--to", required=True, metavar="opencv|colmap|colmap-bin|ros|kalibr|anipose|ply", help=FORMATS_HELP
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="file to write (opencv, kalibr, anipose, ply; an existing directory gets the default file name) "
        "or directory (colmap, colmap-bin, ros; created if absent, files of the same names replaced)",
    )
    parser.add_argument(
        "--observations",
        metavar="OBS.json",
        help="colmap, colmap-bin only: the observations the calibration was solved from, for the 2-D tracks",
    )
    parser.add_argument(
        "--max-error-px",
        type=float,
        help="colmap, colmap-bin only: an observation joins its point's track when its reprojection error is at "
        "most this (default: the solver's rule, 4 sigma_px and at least 1.5 px)",
    )
    parser.add_argument(
        "--unit",
        choices=("m", "mm"),
        help="anipose only: the unit of the translations and so of what aniposelib triangulates "
        "(default m; anipose and FreeMoCap boards are usually in mm)",
    )


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from camnet.errors import InputError
    from camnet.io.atomic import write_directory_atomic, write_text_atomic
    from camnet.io.export import COLMAP_FORMATS, export, is_multi_file
    from camnet.io.formats import load_json, parse_calibration, parse_observations

    if args.max_error_px is not None and (args.to not in COLMAP_FORMATS or args.observations is None):
        raise InputError("--max-error-px: only the colmap exports with --observations use it")
    if args.max_error_px is not None and not args.max_error_px > 0:
        raise InputError(f"--max-error-px: must be positive, got {args.max_error_px}")
    if args.unit is not None and args.to != "anipose":
        raise InputError("--unit: only the anipose export uses it")
    cal = parse_calibration(load_json(args.calibration))
    obs = parse_observations(load_json(args.observations), any_distance=True) if args.observations else None
    files = export(cal, args.to, observations=obs, max_error_px=args.max_error_px, unit=args.unit or "m")
    if is_multi_file(args.to):
        written = write_directory_atomic(args.output, files)
    else:
        ((name, content),) = files.items()
        written = [write_text_atomic(args.output, content, default_name=name)]
    print(json.dumps({"format": args.to, "files": [str(p) for p in written]}), file=sys.stdout)
    return 0
