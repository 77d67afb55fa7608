"""camnet up: calibrate the built-in simulated rig and compare with its ground truth.

Until the live network (drivers, matcher, calibrator on the bus) is in place,
this runs the offline solve on the paper's simulated rig.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.commands.simulate import add_simulation_arguments

    parser.add_argument("--method", choices=("refined", "paper", "unconstrained"), default="refined")
    parser.add_argument("-o", "--output", help="also write the calibration here")
    add_simulation_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.calibrate import Options, calibrate
    from camnet.commands.simulate import simulate_from_args
    from camnet.evaluate import compare, format_comparison
    from camnet.formats import calibration_to_doc, write_json_atomic

    rig, sim = simulate_from_args(args)
    obs = sim.observations
    print(
        f"simulated rig: {len(rig.cameras)} cameras, {len(obs.track_ids)} tracks, "
        f"{len(obs.uv)} observations, noise {args.noise_px} px, seed {args.seed}",
        flush=True,
    )
    result = calibrate(obs, Options(method=args.method))
    if args.output:
        write_json_atomic(args.output, calibration_to_doc(result.calibration))
    print(format_comparison(compare(result.calibration, rig.cameras, rig.points)))
    for warning in result.calibration.extra["diagnostics"]["warnings"]:
        print(f"warning: {warning}")
    return 0
