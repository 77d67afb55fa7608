"""camnet export CALIBRATION.json --to opencv|colmap|ros|kalibr -o OUT"""

from __future__ import annotations

import argparse

FORMATS_HELP = (
    "opencv: FileStorage YAML (one file); colmap: text model (directory); "
    "ros: camera_info YAML per camera (directory); kalibr: camchain YAML (one file)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", help="a camnet.calibration/1 JSON file")
    parser.add_argument("--to", required=True, metavar="opencv|colmap|ros|kalibr", help=FORMATS_HELP)
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="file to write (opencv, kalibr; an existing directory gets the default file name) "
        "or directory (colmap, ros; created if absent, files of the same names replaced)",
    )
    parser.add_argument(
        "--observations",
        metavar="OBS.json",
        help="colmap only: the observations the calibration was solved from, for the 2-D tracks",
    )
    parser.add_argument(
        "--max-error-px",
        type=float,
        help="colmap only: an observation joins its point's track when its reprojection error is at most this "
        "(default: the solver's rule, 4 sigma_px and at least 1.5 px)",
    )


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from camnet.errors import InputError
    from camnet.io.atomic import write_directory_atomic, write_text_atomic
    from camnet.io.export import export, is_multi_file
    from camnet.io.formats import load_json, parse_calibration, parse_observations

    if args.max_error_px is not None and (args.to != "colmap" or args.observations is None):
        raise InputError("--max-error-px: only the colmap export with --observations uses it")
    if args.max_error_px is not None and not args.max_error_px > 0:
        raise InputError(f"--max-error-px: must be positive, got {args.max_error_px}")
    cal = parse_calibration(load_json(args.calibration))
    obs = parse_observations(load_json(args.observations), any_distance=True) if args.observations else None
    files = export(cal, args.to, observations=obs, max_error_px=args.max_error_px)
    if is_multi_file(args.to):
        written = write_directory_atomic(args.output, files)
    else:
        ((name, text),) = files.items()
        written = [write_text_atomic(args.output, text, default_name=name)]
    print(json.dumps({"format": args.to, "files": [str(p) for p in written]}), file=sys.stdout)
    return 0
