"""`camnet replay SESSION.mcap`: publish a recorded session's frames on the live keys."""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus import add_bus_arguments

    parser.add_argument("session", metavar="SESSION.mcap", help="session recorded by camnet record")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, metavar="R",
                      help="speed relative to the recorded pace (default: 1.0)")
    pace.add_argument("--as-fast-as-possible", action="store_true",
                      help="no pacing: publish as fast as the subscribers take the frames")
    parser.add_argument("--rig", metavar="NAME",
                        help="publish under this rig name (default: the recorded rig)")
    parser.add_argument("--include-results", action="store_true",
                        help="also replay the recorded observations and calibrations")
    parser.add_argument("--wait-s", type=float, default=10.0, metavar="S",
                        help="wait up to S seconds for subscribers of every camera (default: 10)")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from camnet.bus import open_session, options_from_args
    from camnet.errors import InputError
    from services.replayer import Replayer, ReplayOptions
    from services.session_file import open_session_file

    if not args.as_fast_as_possible and not args.rate > 0:
        raise InputError(f"--rate: must be > 0, got {args.rate} (or use --as-fast-as-possible)")
    options = ReplayOptions(rate=0.0 if args.as_fast_as_possible else args.rate, rig=args.rig,
                            include_results=args.include_results, wait_s=args.wait_s)
    session_file = open_session_file(args.session)
    tty = sys.stderr.isatty()

    def progress(summary) -> None:
        done = sum(summary.frames.values())
        share = done / summary.total_frames if summary.total_frames else 1.0
        print(f"replay {share:6.1%}: {done}/{summary.total_frames} frames, {summary.duration_s:.1f} s",
              end="\r" if tty else "\n", file=sys.stderr, flush=True)

    with open_session(options_from_args(args)) as session:
        replayer = Replayer(session, session_file, options=options)
        summary = replayer.run(on_progress=progress, progress_period_s=1.0 if tty else 5.0)
    if tty:
        print(file=sys.stderr)
    print("\n".join(summary.lines()))
    return 0
