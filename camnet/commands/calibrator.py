"""`camnet calibrator`: solve the rig's observations as they come and publish the calibration."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path

# camnet.live.policy.LIVE_FREE, spelled out so that building the parser imports no numpy.
DEFAULT_FREE = "f,fisheye,stereo_rotation,stereo_direction"
FRAME_PERIOD_S = 10.0  # camnet.viz.FRAME_PERIOD_S, for the same reason


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments
    from camnet.model.methods import Loss
    from camnet.viz_sinks import add_rerun_arguments

    parser.add_argument("--rig", required=True, metavar="RIG.yaml|NAME",
                        help="the rig file, or just the rig's name")
    parser.add_argument("--state", metavar="FILE.json",
                        help="where the last good calibration is kept and resumed from "
                             "(default: $XDG_STATE_HOME/camnet/<rig>/calibration.json)")
    parser.add_argument("--no-state", action="store_true", help="neither resume nor persist")
    parser.add_argument("--observations-out", metavar="FILE.json",
                        help="on stopping, write the observations behind the last calibration published here "
                             "(camnet.observations/1, with the frame sets and capture time that calibration names)")
    parser.add_argument("--free", default=DEFAULT_FREE,
                        help="intrinsics to estimate: a comma list of f, aspect, pp, k1, k2, fisheye, "
                             "stereo_rotation, stereo_direction, or 'auto' for the engine's rule (default: "
                             "%(default)s; principal points and pinhole distortion are held as given, see "
                             "camnet/live/policy.py; a rig file with the pair's pose, stereo.R and "
                             "stereo.t, holds the pair: default f,fisheye)")
    parser.add_argument("--loss", choices=tuple(loss.value for loss in Loss), default=Loss.CAUCHY.value,
                        help="robust loss of the adjustment (default cauchy)")
    parser.add_argument("--max-rms-px", type=float, default=3.0,
                        help="a solution with a larger reprojection RMS is not trusted (default 3)")
    parser.add_argument("--max-scale-rel", type=float, default=0.05,
                        help="a solution whose scale is less certain (1 sigma, relative) is not trusted "
                             "(default 0.05)")
    parser.add_argument("--session-id", metavar="HEX",
                        help="this node's Zenoh session id, 32 hex digits: its calibrations state it as their "
                             "source (camnet up gives its calibrator one, to tell them from other publishers')")
    parser.add_argument("--lockstep", action="store_true",
                        help="acknowledge every observations message once solved, for `camnet replay --lockstep`")
    add_rerun_arguments(parser)
    parser.add_argument("--rerun-frame-period-s", type=float, default=FRAME_PERIOD_S, metavar="S",
                        help="log a camera's latest frame to Rerun with a solve at most every S seconds of "
                             "capture time, and always its first and when it is taken for moved; 0: at every "
                             "solve (default %(default)s; the frames' JPEGs are most of what a solve adds)")
    add_bus_arguments(parser)


def load_rig_arg(value: str):
    """(name, Rig or None) of `--rig`: a rig file, or just a rig's name."""
    from camnet.bus.keys import validate_id
    from camnet.io.rig import load_rig

    if value.endswith((".yaml", ".yml")) or os.path.sep in value:
        rig = load_rig(value)
        return rig.name, rig
    return validate_id(value, what="--rig"), None


def default_state_path(rig: str) -> Path:
    base = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(base) / "camnet" / rig / "calibration.json"


def run(args: argparse.Namespace) -> int:
    import socket

    from camnet.bus.session import joined, options_from_args
    from camnet.bus.source import check_session_id
    from camnet.commands.calibrate import parse_free
    from camnet.errors import InputError
    from camnet.live.policy import LiveConfig, SoundnessLimits
    from camnet.services.calibrator import CalibratorConfig, CalibratorNode, RerunView, untrusted_state
    from camnet.solve import Options
    from camnet.solve.options import World
    from camnet.viz import close_recording, open_recording
    from camnet.viz_sinks import sinks_from_args

    name, rig = load_rig_arg(args.rig)
    sinks = sinks_from_args(args)
    for flag, value in (("--max-rms-px", args.max_rms_px), ("--max-scale-rel", args.max_scale_rel)):
        if not value > 0:
            raise InputError(f"{flag}: must be positive, got {value}")
    if not 0 <= args.rerun_frame_period_s < float("inf"):
        raise InputError(f"--rerun-frame-period-s: must be 0 or more seconds, got {args.rerun_frame_period_s}")
    if args.session_id is not None:
        check_session_id(args.session_id)
    state = None
    if not args.no_state:
        state = Path(args.state) if args.state else default_state_path(name)
        state.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        if (problem := untrusted_state(state)) is not None:  # said before joining the bus
            raise InputError(f"--state {problem}")
    free, stereo_pose = parse_free(args.free), None
    if rig is not None and rig.stereo is not None and rig.stereo.R is not None:
        stereo_pose = (rig.stereo.R, rig.stereo.t)
        if args.free == DEFAULT_FREE:  # a factory head: its pose is known, only the scene's cameras move
            free = frozenset({"f", "fisheye"})
    options = Options(free=free, loss=args.loss, world=rig.world if rig is not None else World.LEFT_CAMERA)
    tolerance = None if rig is None or rig.stereo is None else rig.stereo.tolerance_deg
    if stereo_pose is not None or tolerance is not None:
        # A given pose is held as given, as a fixed K is, unless the rig file says to what it is known.
        options = replace(options, pair_tolerance_deg=tolerance or 0.0)
    live = LiveConfig(options=options, stereo_pose=stereo_pose,
                      limits=SoundnessLimits(max_rms_px=args.max_rms_px), max_scale_rel=args.max_scale_rel)
    config = CalibratorConfig(live=live, state_path=state,
                              observations_path=Path(args.observations_out) if args.observations_out else None)
    rec = open_recording(rig=name, sinks=sinks)
    try:
        for sink in sinks:
            print(f"rerun: {sink.describe(host=socket.gethostname())}", flush=True)
        truth = (rig.simulated_truth() if rig is not None else []) or None
        viewer = RerunView(rec, truth=truth, frame_period_s=args.rerun_frame_period_s) if rec is not None else None
        with joined(replace(options_from_args(args), session_id=args.session_id)) as session:
            CalibratorNode(session, name, config, viewer=viewer, lockstep=args.lockstep, rig=rig).run()
    finally:
        close_recording(rec)
    return 0
