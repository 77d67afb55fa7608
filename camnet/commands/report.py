"""camnet report CALIBRATION.json [--observations OBS.json] [--truth TRUTH.json] -o REPORT.html"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", help="a camnet.calibration/1 JSON file")
    parser.add_argument(
        "--observations",
        metavar="OBS.json",
        help="the observations the calibration was solved from: adds the per-point errors and residual histograms",
    )
    parser.add_argument(
        "--truth",
        metavar="TRUTH.json",
        help="the ground truth of a simulated rig, a calibration file (truth.json of a simulated run of camnet up, "
        "camnet simulate --truth): adds the calibration's errors against it",
    )
    parser.add_argument(
        "-o", "--output", required=True, help="HTML file to write (an existing directory gets report.html)"
    )


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    from pathlib import Path

    from camnet.io.atomic import write_text_atomic
    from camnet.io.formats import load_json, parse_calibration, parse_observations
    from camnet.io.report import render_report

    cal = parse_calibration(load_json(args.calibration))
    obs = parse_observations(load_json(args.observations), any_distance=True) if args.observations else None
    truth = list(parse_calibration(load_json(args.truth)).cameras) if args.truth else None
    page = render_report(cal, obs, title=f"camnet calibration: {Path(args.calibration).name}", truth=truth)
    path = write_text_atomic(args.output, page, default_name="report.html")
    print(json.dumps({"output": str(path), "bytes": len(page.encode())}), file=sys.stdout)
    return 0
