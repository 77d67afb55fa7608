"""camnet simulate -o OBSERVATIONS.json [--truth CALIBRATION.json]"""

from __future__ import annotations

import argparse


def add_simulation_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags that describe a simulated rig; shared with `camnet up`."""
    parser.add_argument("--cameras", type=int, default=4, help="cameras in the network (>= 3; default 4)")
    parser.add_argument("--points", type=int, default=57, help="scene points (default 57, as in the paper)")
    parser.add_argument("--noise-px", type=float, default=0.5, help="pixel noise sigma (default 0.5)")
    parser.add_argument("--outliers", type=float, default=0.0, help="share of wrong tracks, 0..1")
    parser.add_argument(
        "--visibility", type=float, default=1.0, help="share of tracks each non-stereo camera sees, 0..1"
    )
    parser.add_argument(
        "--pp-offset-px", type=float, default=0.0, help="principal points drawn within this many pixels of the centre"
    )
    parser.add_argument(
        "--second-head", action="store_true",
        help="give mono_b a parallel partner 0.125 m to its right, their distance a further known one",
    )
    parser.add_argument("--seed", type=int, default=0)


def simulate_from_args(args: argparse.Namespace):
    from camnet.errors import InputError
    from camnet.sim.simulate import make_rig, observe, with_head

    if args.cameras < 3:
        raise InputError(f"--cameras: a metric solve needs at least 3, got {args.cameras}")
    if args.points < 4:
        raise InputError(f"--points: need at least 4, got {args.points}")
    for name in ("outliers", "visibility"):
        value = getattr(args, name)
        if not 0.0 <= value <= 1.0:
            raise InputError(f"--{name}: must lie in [0, 1], got {value}")
    if args.noise_px < 0:
        raise InputError(f"--noise-px: must not be negative, got {args.noise_px}")
    rig = make_rig(n_cameras=args.cameras, n_points=args.points, seed=args.seed, pp_offset_px=args.pp_offset_px)
    if args.second_head:
        if args.cameras < 4:
            raise InputError(f"--second-head: pairs with mono_b, the fourth camera; --cameras is {args.cameras}")
        rig = with_head(rig, "mono_b")
    sim = observe(
        rig, noise_px=args.noise_px, seed=args.seed, outlier_fraction=args.outliers, visibility=args.visibility
    )
    return rig, sim


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", required=True, help="observations file to write")
    parser.add_argument("--truth", help="also write the ground truth as a calibration file")
    add_simulation_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import sys

    import numpy as np

    from camnet.io.formats import calibration_to_doc, observations_to_doc, write_json_atomic
    from camnet.model.calibration import Calibration

    rig, sim = simulate_from_args(args)
    obs = sim.observations
    write_json_atomic(args.output, observations_to_doc(obs))
    print(f"camnet simulate: wrote {args.output}: {len(obs.cameras)} cameras, {len(obs.track_ids)} tracks, "
          f"{len(obs.uv)} observations ({int(sim.outlier_obs.sum())} of them false), noise {args.noise_px} px",
          file=sys.stderr)
    if args.truth:
        truth = Calibration(tuple(rig.cameras), np.arange(len(rig.points)), rig.points, 0.0, rig.cameras[0].id)
        write_json_atomic(args.truth, calibration_to_doc(truth))
        print(f"camnet simulate: wrote the ground truth to {args.truth}", file=sys.stderr)
    print(f"next: camnet calibrate {args.output} -o calibration.json", file=sys.stderr)
    return 0
