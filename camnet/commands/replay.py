"""`camnet replay SESSION.mcap`: publish a recorded session's frames on the live keys."""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments

    parser.add_argument("session", metavar="SESSION.mcap", help="session recorded by camnet record")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, metavar="R",
                      help="speed relative to the recorded pace (default: 1.0)")
    pace.add_argument("--as-fast-as-possible", action="store_true",
                      help="no pacing: publish as fast as the subscribers take the frames")
    pace.add_argument("--lockstep", action="store_true",
                      help="one capture instant at a time: publish its frames, then wait until the matcher and "
                           "the calibrator (both run with --lockstep) are done with them; two replays then give "
                           "the same calibrations to the last digit (docs/session-format.md)")
    parser.add_argument("--rig", metavar="NAME",
                        help="publish under this rig name (default: the recorded rig)")
    parser.add_argument("--include-results", action="store_true",
                        help="also replay the recorded observations and calibrations")
    parser.add_argument("--wait-s", type=float, default=10.0, metavar="S",
                        help="wait up to S seconds for subscribers of every camera (default: 10)")
    parser.add_argument("--step-tolerance-ms", type=float, default=5.0, metavar="MS",
                        help="lockstep: frames whose capture times are this close are one step (default: 5)")
    parser.add_argument("--ack-timeout-s", type=float, default=120.0, metavar="S",
                        help="lockstep: fail when the matcher or calibrator is silent this long (default: 120)")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus.session import joined, options_from_args
    from camnet.errors import InputError
    from camnet.io.session_file import open_session_file
    from camnet.services.replayer import Replayer, ReplayOptions

    if not args.as_fast_as_possible and not args.rate > 0:
        raise InputError(f"--rate: must be > 0, got {args.rate} (or use --as-fast-as-possible)")
    if not args.step_tolerance_ms >= 0:
        raise InputError(f"--step-tolerance-ms: must be >= 0, got {args.step_tolerance_ms}")
    if not args.ack_timeout_s > 0:
        raise InputError(f"--ack-timeout-s: must be positive, got {args.ack_timeout_s}")
    unpaced = args.as_fast_as_possible or args.lockstep
    options = ReplayOptions(rate=0.0 if unpaced else args.rate, rig=args.rig,
                            include_results=args.include_results, wait_s=args.wait_s, lockstep=args.lockstep,
                            step_tolerance_ms=args.step_tolerance_ms, ack_timeout_s=args.ack_timeout_s)
    session_file = open_session_file(args.session)
    tty = sys.stderr.isatty()

    def progress(summary) -> None:
        done = sum(summary.frames.values())
        share = done / summary.total_frames if summary.total_frames else 1.0
        print(f"replay {share:6.1%}: {done}/{summary.total_frames} frames, {summary.duration_s:.1f} s",
              end="\r" if tty else "\n", file=sys.stderr, flush=True)

    with joined(options_from_args(args)) as session:
        replayer = Replayer(session, session_file, options=options)
        summary = replayer.run(on_progress=progress, progress_period_s=1.0 if tty else 5.0)
    if tty:
        print(file=sys.stderr)
    print("\n".join(summary.lines()))
    return 0
