"""camnet calibrate OBSERVATIONS.json -o CALIBRATION.json"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from typing import TYPE_CHECKING

from camnet.model.methods import Loss, Method

if TYPE_CHECKING:
    from camnet.model.calibration import Calibration
    from camnet.model.observations import Observations
    from camnet.solve import Options

FREE_HELP = (
    "intrinsics to estimate: 'auto' (default: focal lengths, then whatever the data "
    "determine) or a comma list of f, aspect, pp, k1, k2, fisheye, stereo_rotation, stereo_direction"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("observations", help="a camnet.observations/1 JSON file")
    parser.add_argument("-o", "--output", required=True, help="where to write camnet.calibration/1 JSON")
    parser.add_argument(
        "--method",
        choices=tuple(m.value for m in Method),
        default=Method.REFINED.value,
        help="refined: baseline-constrained bundle adjustment (default); paper: the paper's "
        "solver alone; unconstrained: bundle adjustment that lets the scale float (for comparison)",
    )
    parser.add_argument(
        "--loss",
        choices=tuple(loss.value for loss in Loss),
        default=Loss.CAUCHY.value,
        help="robust loss of the first adjustment (default cauchy)",
    )
    parser.add_argument("--loss-scale-px", type=float, default=2.0, help="residual at which the robust loss bends")
    parser.add_argument("--free", default="auto", help=FREE_HELP)
    parser.add_argument(
        "--initial",
        metavar="CALIBRATION.json",
        help="warm start from a previous calibration of the same rig",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the RANSAC sampling")
    parser.add_argument("--json", action="store_true",
                        help="also print a one-line JSON summary on stdout (the human summary goes to stderr)")
    parser.add_argument("--accept-any-distance", action="store_true",
                        help="accept known distances outside 0.005-50 m (refused as a likely unit mistake)")
    parser.add_argument("--max-tracks", type=int, default=None, metavar="N",
                        help="most tracks one solve takes (default 20000: more take minutes and gigabytes); "
                             "a file with more is refused unless --subsample-tracks")
    parser.add_argument("--subsample-tracks", action="store_true",
                        help="solve --max-tracks tracks drawn at random (with --seed) from a larger file")
    parser.add_argument(
        "--pp-prior-rel",
        type=float,
        default=0.01,
        help="1 sigma of a principal point nobody gave, about the image centre, as a fraction of the image size, "
        "in the reported uncertainty (0: sigmas conditional on the centre being right)",
    )
    parser.add_argument(
        "--world", choices=("left_camera", "floor"), default="left_camera",
        help="the frame the calibration is written in: the left stereo camera's (default), or the floor's found "
        "from the scene (Z up, origin on the floor below the capture volume, X toward the stereo pair)",
    )
    parser.add_argument(
        "--pair-tolerance-deg", type=float, default=None, metavar="DEG",
        help="1 sigma, degrees, to which a stereo pair held parallel (or at the rotation --initial gives) is known, "
        "in the reported uncertainty (default 0.08: a head sold as parallel, and 0 for a pose --initial gives; "
        "a factory-rectified head is 0.01-0.02; 0: sigmas conditional on the held rotation)",
    )


def parse_free(value: str) -> str | frozenset[str]:
    """The --free flag: "auto" or the set of names (the engine checks them)."""
    return "auto" if value == "auto" else frozenset(s.strip() for s in value.split(",") if s.strip())


# Inputs from this size on say on stderr what they are doing: a solve may then take minutes.
PROGRESS_FILE_BYTES = 5_000_000
PROGRESS_TRACKS = 5_000


class Progress:
    """Stage lines on stderr with the seconds since start, only for large inputs (stdout stays JSON)."""

    def __init__(self, path: str) -> None:
        import os
        import time

        self._start_s = time.monotonic()
        try:
            self.on = os.path.getsize(path) >= PROGRESS_FILE_BYTES
        except OSError:
            self.on = False

    def say(self, message: str) -> None:
        import time

        if self.on:
            print(f"camnet calibrate: {time.monotonic() - self._start_s:6.1f} s  {message}", file=sys.stderr,
                  flush=True)


def run(args: argparse.Namespace) -> int:
    from camnet.errors import InputError
    from camnet.io.formats import (
        calibration_to_doc,
        load_json,
        parse_calibration,
        parse_observations,
        write_json_atomic,
    )
    from camnet.io.summary import summary_lines
    from camnet.solve import Options
    from camnet.solve.options import World
    from camnet.solve.report.verdict import judge

    if not args.loss_scale_px > 0:
        raise InputError(f"--loss-scale-px: must be positive, got {args.loss_scale_px}")
    if not 0 <= args.pp_prior_rel < 1:
        raise InputError(f"--pp-prior-rel: must be in [0, 1), got {args.pp_prior_rel}")
    if args.pair_tolerance_deg is not None and not 0 <= args.pair_tolerance_deg < 10:
        raise InputError(f"--pair-tolerance-deg: must be in [0, 10) degrees, got {args.pair_tolerance_deg}")
    from camnet.io.formats import MAX_TRACKS

    max_tracks = MAX_TRACKS if args.max_tracks is None else args.max_tracks
    if max_tracks < 1:
        raise InputError(f"--max-tracks: must be at least 1, got {max_tracks}")
    free = parse_free(args.free)
    progress = Progress(args.observations)
    progress.say(f"reading {args.observations}")
    doc = load_json(args.observations)
    obs = parse_observations(doc, any_distance=args.accept_any_distance, max_tracks=max_tracks,
                             subsample_seed=args.seed if args.subsample_tracks else None)
    progress.on = progress.on or len(obs.track_ids) >= PROGRESS_TRACKS
    if len(doc["tracks"]) > len(obs.track_ids):
        print(f"camnet calibrate: warning: solving {len(obs.track_ids)} of the {len(doc['tracks'])} tracks, "
              f"drawn at random (--seed {args.seed})", file=sys.stderr)
    progress.say(f"solving {len(obs.track_ids)} tracks, {len(obs.uv)} observations, {len(obs.cameras)} cameras")
    initial = parse_calibration(load_json(args.initial)) if args.initial else None
    options = Options(method=Method(args.method), loss=Loss(args.loss), loss_scale_px=args.loss_scale_px, free=free,
                      seed=args.seed, pp_prior_rel=args.pp_prior_rel, world=World(args.world))
    if args.pair_tolerance_deg is not None:
        options = replace(options, pair_tolerance_deg=args.pair_tolerance_deg)
    cal = _solve(obs, options, initial, progress)
    write_json_atomic(args.output, calibration_to_doc(cal))
    print("\n".join([f"camnet calibrate: wrote {args.output}", *summary_lines(cal)]), file=sys.stderr)
    if not args.json:
        return 0
    verdict = judge(cal)
    summary = {
        "output": args.output,
        "cameras": len(cal.cameras),
        "points": len(cal.points),
        "rms_reprojection_px": round(cal.rms_reprojection_px, 4),
        "scale_sigma_rel": cal.uncertainty.scale_rel.value if cal.uncertainty is not None else None,
        "cameras_left_out": dict(cal.report.cameras_left_out) if cal.report is not None else {},
        "verdict": verdict.level.value if verdict is not None else None,
        "warnings": list(cal.warnings),
        "notes": list(cal.report.notes) if cal.report is not None else [],
    }
    print(json.dumps(summary), file=sys.stdout)
    return 0


def _solve(obs: Observations, options: Options, initial: Calibration | None, progress: Progress) -> Calibration:
    """The calibration of `obs`, or SolveError saying why there is none (nothing is written then)."""
    from camnet.errors import SolveError
    from camnet.live.judged_solve import Status
    from camnet.live.newest_first import solve_newest_first
    from camnet.live.policy import SCALE_UNDETERMINED, soundness_check
    from camnet.solve import calibrate

    if initial is None and options.method == Method.REFINED:
        # Solved as the live calibrator solves without a calibration (camnet.live.newest_first): a long
        # pool on its newest tracks first, cameras placed wrong left out and named. What the live policy's
        # limits of soundness still refuse is wrong (absurd focal lengths, cameras that keep too few of their
        # observations, a large RMS): refused here too, nothing written. A large scale sigma is not wrong,
        # only uncertain, and is reported as it is: the live limit on it is no part of the check.
        judged = solve_newest_first(obs, options, soundness_check)
        progress.say(f"solved ({judged.status})")
        if judged.status == Status.REJECTED and judged.reason.startswith(SCALE_UNDETERMINED):
            raise SolveError(f"the calibration is refused: {judged.reason}")  # the reason says what to give
        if judged.status == Status.REJECTED:
            raise SolveError(f"the calibration is refused: {judged.reason}; check the cameras named (their "
                             "matches, their sync, whether they moved), or leave them out of the observations")
        if judged.status == Status.FAILED:
            raise SolveError(judged.reason)  # the last solve's own error (not solved again to raise it)
        return judged.calibration
    result = calibrate(obs, options, initial=initial)  # a warm start, or another method
    progress.say("solved" if result.converged else "not converged")
    if not result.converged:
        raise SolveError(f"the adjustment did not converge: {result.reason}")
    return result.calibration
