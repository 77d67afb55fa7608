"""The `camnet` command line."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from camnet import __version__
from camnet.errors import CamnetError

# name -> module in camnet.commands; order is the order shown in --help.
COMMANDS = {
    "up": "Run the whole network (drivers, matcher, calibrator) on this machine; default: the simulated rig.",
    "cameras": "List the cameras this host sees (V4L2, GenICam) with their modes; --preview streams them.",
    "init": "Write a rig file of the cameras found: the stereo pair and its baseline.",
    "match": "Match one synchronised image per camera into an observations file.",
    "calibrate": "Solve a calibration offline from an observations file.",
    "simulate": "Write the observations of a simulated rig (and its ground truth).",
    "driver": "Run one camera driver (sim, aravis, v4l2) and publish its frames.",
    "features": "Detect one camera's features from its frames on the bus and publish them (a feature stage).",
    "matcher": "Match a rig's frames into tracks and publish them as observations.",
    "calibrator": "Solve the rig's observations as they come; publish and keep the calibration.",
    "router": "Run an embedded Zenoh router.",
    "record": "Record everything a rig publishes into an MCAP session file.",
    "replay": "Publish a recorded session's frames on the live keys.",
    "status": "List the live nodes of a rig with their frame rates and drops.",
    "secure": "Write a rig's CA and certificates, for nodes that join with --secure DIR.",
    "export": "Write a calibration for OpenCV, COLMAP, ROS, Kalibr, anipose, or its points as PLY.",
    "report": "Write an HTML report of a calibration: errors, uncertainty, layout.",
    "fuse": "Place two calibrated sites in one metric space, floors coinciding, facing each other.",
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line; with `only`, just that sub-command's arguments are built.

    Building a sub-command's arguments imports its module (and what its flags'
    choices come from), so `camnet --help` and each command's start import
    only what that command needs.
    """
    parser = argparse.ArgumentParser(
        prog="camnet",
        description="True-to-scale auto calibration of camera networks.",
    )
    parser.add_argument("--version", action="version", version=f"camnet {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, summary in COMMANDS.items():
        command_parser = sub.add_parser(name, help=summary, description=summary)
        if only is None or name == only:
            module = importlib.import_module(f"camnet.commands.{name}")
            module.add_arguments(command_parser)
            command_parser.set_defaults(run=module.run)
    return parser


def _command(argv: list[str]) -> str | None:
    """The sub-command named on the command line (the first word that is one), if any."""
    return next((word for word in argv if word in COMMANDS), None)


def quiet_opencv() -> None:
    """Keep OpenCV's own log lines (``[ WARN:0@0.062] global cap.cpp:212 ...``) out of camnet's output.

    camnet says itself what fails, naming the camera. The environment
    variables reach OpenCV (and the FFmpeg inside it, ``[mov,mp4,...] moov
    atom not found``) when it is imported, here and in the child nodes
    (`camnet up`); an OPENCV_LOG_LEVEL the user set is kept.
    """
    if "OPENCV_LOG_LEVEL" in os.environ:
        return
    os.environ["OPENCV_LOG_LEVEL"] = "SILENT"
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    if "cv2" in sys.modules:  # imported already (camnet called from Python): tell it directly
        cv2 = sys.modules["cv2"]
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(only=_command(argv) or "")
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    quiet_opencv()
    # Each node's one status line every few seconds (camnet.bus.node.Presence) shows at the default level.
    logging.getLogger("camnet.status").setLevel(min(level, logging.INFO))
    try:
        return int(args.run(args) or 0)
    except CamnetError as exc:
        print(f"camnet {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
