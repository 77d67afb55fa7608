"""`camnet record --rig NAME -o SESSION.mcap`: record everything a rig publishes."""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments
    from camnet.services.recorder import ChunkCompression

    parser.add_argument("--rig", required=True, metavar="NAME", help="rig name (as in its file)")
    parser.add_argument("-o", "--output", required=True, metavar="SESSION.mcap",
                        help="MCAP file to write (refused if it exists, unless --force); an existing "
                             "directory gets a new <rig>-<UTC time>.mcap in it")
    parser.add_argument("--duration-s", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C or SIGTERM); a recorder that fell "
                             "behind writes its queue for at most 1 s more, then drops the rest, counted")
    parser.add_argument("--compression", type=ChunkCompression, choices=list(ChunkCompression),
                        default=ChunkCompression.LZ4,
                        help="chunk compression (default: lz4; zstd makes smaller files but "
                             "costs much more CPU)")
    parser.add_argument("--flush-period-s", type=float, default=1.0, metavar="S",
                        help="write out the chunk in progress at least this often; what is "
                             "written survives a killed recorder (default: 1)")
    parser.add_argument("--queue-mb", type=float, default=512.0, metavar="MB",
                        help="bound of the receive queue; a full queue loses messages, counted "
                             "(default: 512)")
    parser.add_argument("--id", default="recorder", metavar="ID",
                        help="node id of this recorder (default: recorder)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from camnet.bus.session import joined, options_from_args
    from camnet.services.recorder import Recorder, RecorderConfig

    output = Path(args.output)
    if output.is_dir():
        # A restarted recorder (e.g. a container) starts a new file and never overwrites the last one.
        output = output / f"{args.rig}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}.mcap"
    config = RecorderConfig(rig=args.rig, path=output, duration_s=args.duration_s,
                            compression=args.compression, flush_period_s=args.flush_period_s,
                            queue_capacity_bytes=int(args.queue_mb * 1e6), node_id=args.id,
                            overwrite=args.force)
    tty = sys.stderr.isatty()

    def progress(summary) -> None:
        frames = sum(t.frames for t in summary.cameras.values())
        missing = sum(t.missing for t in summary.cameras.values())
        line = (f"recording {summary.duration_s:6.1f} s: {len(summary.cameras)} camera(s), "
                f"{frames} frames, {missing} missing, {summary.queue_overflows} refused by the full queue, "
                f"{summary.file_bytes / 1e6:.0f} MB")
        print(line, end="\r" if tty else "\n", file=sys.stderr, flush=True)

    with joined(options_from_args(args)) as session:
        summary = Recorder(session, config).run(on_progress=progress,
                                                progress_period_s=1.0 if tty else 5.0)
    if tty:
        print(file=sys.stderr)
    print("\n".join(summary.lines()))
    return 0
