"""`camnet up [RIG.yaml]`: the whole network on this machine, calibrating itself.

Starts one driver per camera, the matcher and the calibrator as child
processes on the bus (restarting one that exits after it came up,
camnet.bus.launch), follows the calibrations its calibrator publishes, and
ends (after `--duration-s`, or never with `--forever`; with
`--until-frame-sets N` at the first calibration from N pooled frame sets)
by printing the calibrator's last, read from its state file, beside the
ground truth when the rig is simulated. With no rig file it runs the
built-in simulated rig: the paper's four cameras.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from camnet.io.messages import CalibrationMessage

# The built-in rig, config/sim.yaml: installed with camnet as camnet/rigs/sim.yaml
# (pyproject.toml), read from config/ in a source checkout (an editable install).
INSTALLED_RIG = Path(__file__).resolve().parents[1] / "rigs" / "sim.yaml"
SOURCE_RIG = Path(__file__).resolve().parents[2] / "config" / "sim.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.bus.session import add_bus_arguments
    from camnet.commands.calibrator import FRAME_PERIOD_S
    from camnet.matching.features import Detector
    from camnet.viz_sinks import add_rerun_arguments

    parser.add_argument("rig_file", nargs="?", metavar="RIG.yaml",
                        help="rig file (default: the built-in simulated rig, config/sim.yaml)")
    parser.add_argument("--duration-s", type=float, default=60.0,
                        help="seconds to run before printing the result and stopping (default 60)")
    parser.add_argument("--forever", action="store_true", help="run until interrupted")
    parser.add_argument("--until-frame-sets", type=int, metavar="N",
                        help="end at the first calibration solved from at least N pooled frame sets, however long "
                             "the machine takes to pool them; --duration-s (or --forever) bounds the wait, and a "
                             "run that ends before is an error")
    parser.add_argument("--detector", type=Detector, choices=list(Detector), default=Detector.SIFT,
                        help="matcher features (default: sift)")
    parser.add_argument("--features", action="store_true",
                        help="run each driver with its feature stage (camnet driver --features): features are "
                             "detected beside each camera and the matcher only matches")
    parser.add_argument("--out", "--run-dir", dest="out", metavar="DIR",
                        help="the run directory: the last calibration, its observations, report.html, the exports "
                             "and the nodes' logs (default: runs/<rig>-<time> under the working directory)")
    parser.add_argument("--replay", metavar="SESSION.mcap",
                        help="feed the matcher a recorded session (camnet record) instead of the rig's drivers; "
                             "the run ends after the session and the calibration of its last frames")
    parser.add_argument("-o", "--output", metavar="CALIBRATION.json", help="also write the final calibration here")
    parser.add_argument("--record", metavar="SESSION.mcap",
                        help="also run the recorder: everything the rig publishes goes into this MCAP file")
    parser.add_argument("--no-restart", action="store_true",
                        help="end the run when any node exits (default: a node that exits after it came up on "
                             "the bus is restarted, after 1 s doubling to 10 s, at most 5 times a minute; one that "
                             "exits before ends the run)")
    parser.add_argument("--progress-jsonl", metavar="FILE",
                        help="also write one JSON line per calibration (what the progress lines show)")
    add_rerun_arguments(parser)
    parser.add_argument("--rerun-frame-period-s", type=float, default=FRAME_PERIOD_S, metavar="S",
                        help="the calibrator's: log a camera's latest frame to Rerun with a solve at most every S "
                             "seconds of capture time, and always its first and when it is taken for moved; 0: at "
                             "every solve (default %(default)s)")
    add_bus_arguments(parser)


def default_rig() -> Path:
    """The rig `camnet up` runs without a rig file: the installed copy, else the source tree's."""
    return INSTALLED_RIG if INSTALLED_RIG.is_file() else SOURCE_RIG


def _checked_rig(args: argparse.Namespace):
    """(rig path, Rig) of the command, once its flags are known to be usable; InputError if not."""
    from camnet.errors import InputError
    from camnet.io.rig import load_rig
    from camnet.viz_sinks import sinks_from_args

    rig_path = Path(args.rig_file) if args.rig_file else default_rig()
    rig = load_rig(rig_path)
    if rig.stereo is None:
        raise InputError(f"{rig_path}: the rig has no stereo pair; camnet needs one with a known baseline (add a "
                         "'stereo:' section with left, right and baseline_m)")
    for i, entry in enumerate(rig.cameras):
        if entry.driver is None and not args.replay:
            raise InputError(f"{rig_path}: cameras[{i}] ({entry.id}) has no driver; camnet up runs one per camera "
                             "(a rig of image files is for camnet match)")
    if not args.replay:
        _check_sources(rig_path, rig)
    if not args.duration_s > 0:
        raise InputError(f"--duration-s: must be positive, got {args.duration_s}")
    if args.until_frame_sets is not None and args.until_frame_sets < 1:
        raise InputError(f"--until-frame-sets: must be 1 or more, got {args.until_frame_sets}")
    if args.record and Path(args.record).exists() and not Path(args.record).is_dir():
        raise InputError(f"--record: {args.record} exists; camnet never overwrites a session")
    if args.replay and not Path(args.replay).is_file():
        raise InputError(f"--replay: {args.replay} is no file")
    if args.replay and args.features:
        raise InputError("--features: a replay runs no drivers; its session holds the features it recorded, if any")
    if args.replay and args.record:
        raise InputError("--record: a replay is recorded already; give --replay or --record, not both")
    sinks_from_args(args)  # refuse a bad --rerun here, before anything is written or started
    if not 0 <= args.rerun_frame_period_s < float("inf"):  # the calibrator's check, before it is started
        raise InputError(f"--rerun-frame-period-s: must be 0 or more seconds, got {args.rerun_frame_period_s}")
    return rig_path, rig


def _check_sources(rig_path: Path, rig) -> None:
    """Refuse, naming every one of them at once, the cameras whose source is absent (v4l2 devices, files)."""
    from camnet.errors import InputError

    problems = []
    for entry in rig.cameras:
        if entry.driver == "v4l2":
            from camnet.drivers.v4l2 import source_problem

            problems.append(source_problem(entry.id, entry.config))
    problems = [p for p in problems if p is not None]
    if len(problems) == 1:
        raise InputError(f"{rig_path}: {problems[0]}")
    if problems:
        raise InputError("\n".join([f"{rig_path}: {len(problems)} of {len(rig.cameras)} cameras cannot start:",
                                    *(f"  {p}" for p in problems)]))


class LatestCalibration:
    """Subscriber callback keeping the latest valid calibration message of the rig's calibrator (`latest`),
    and every one that arrived since the last `take`, in order (a few at most: two solves in quick
    succession are both shown, not just the second).

    Any peer may publish on the calibration key: what is no calibration, and
    a calibration whose sample does not state the calibrator's session
    (`source`, camnet.bus.source) as its source, are counted and logged once
    per kind, never shown or kept.
    """

    PENDING = 32  # kept for `take`; beyond, the oldest go (the console is that far behind)

    def __init__(self, source: str | None = None) -> None:
        import collections
        import logging
        import threading

        from camnet.bus.node import Tally

        self.latest: CalibrationMessage | None = None
        self.arrived = threading.Event()
        self.malformed = Tally(logging.getLogger("camnet.up"))
        self.source = source
        self.foreign = Tally(logging.getLogger("camnet.up"))  # well-formed, from another publisher
        self._pending: collections.deque[CalibrationMessage] = collections.deque(maxlen=self.PENDING)
        self._lock = threading.Lock()

    def __call__(self, sample) -> None:
        from camnet.bus.source import sample_source
        from camnet.io.messages import MessageError, decode_calibration_message

        try:
            message = decode_calibration_message(sample.payload.to_bytes())
        except MessageError as exc:
            self.malformed.count(exc.kind, "ignoring a message that is no calibration (%s)", exc)
            return
        if self.source is not None and (source := sample_source(sample)) != self.source:
            self.foreign.count("other publisher", "ignoring a calibration that is not the rig's calibrator's "
                               "(its source: %s)", source or "not stated")
            return
        with self._lock:
            self._pending.append(message)
            self.latest = message
        self.arrived.set()

    def take(self) -> list[CalibrationMessage]:
        """The calibration messages that arrived since the last call, oldest first."""
        with self._lock:
            messages = list(self._pending)
            self._pending.clear()
        return messages


class RunFollower:
    """What `camnet up` follows on the bus: the calibrator's calibrations (progress lines)."""

    def __init__(self, args: argparse.Namespace, truth, calibrator_id: str | None = None) -> None:
        self.args, self.truth = args, truth
        self.on_calibration = LatestCalibration(calibrator_id)
        self.reached: CalibrationMessage | None = None  # the first calibration from --until-frame-sets frame sets

    def follow(self, launch, stop, start_s: float, run_dir: Path, progress_file) -> None:
        """Print a line per calibration until the duration is up, Ctrl-C, a replay's end, or the first
        calibration from --until-frame-sets frame sets (kept in `reached`)."""
        import json
        import time

        from camnet.commands.up_console import progress_line, summarise

        next_wait_note = start_s + 10.0
        numbering = SolveNumbering()
        replay_done_s = None
        while ((self.args.forever or time.monotonic() - start_s < self.args.duration_s) and not stop.is_set()
               and self.reached is None):
            replay_done_s = replay_done_s or _replay_ended(launch)
            if replay_done_s is not None and time.monotonic() - replay_done_s > REPLAY_TAIL_S:
                break  # the matcher's last pool has been solved by now, or never will be
            launch.check()
            if self.on_calibration.arrived.wait(timeout=0.5):
                self.on_calibration.arrived.clear()
                for message in self.on_calibration.take():
                    summary = summarise(time.monotonic() - start_s, message, self.truth)
                    note = numbering.note(message.solve, run_dir, resumed=message.resumed)
                    print(progress_line(summary) + note, flush=True)
                    if progress_file is not None:
                        progress_file.write(json.dumps(summary) + "\n")
                        progress_file.flush()
                    wanted = self.args.until_frame_sets
                    if self.reached is None and wanted is not None and (message.frame_sets or 0) >= wanted:
                        self.reached = message
            elif self.on_calibration.latest is None and time.monotonic() >= next_wait_note:
                print(f"{time.monotonic() - start_s:7.1f} s  waiting for the first calibration "
                      f"(see {run_dir / 'logs'}/*.log)", flush=True)
                next_wait_note = time.monotonic() + 10.0


class SolveNumbering:
    """What the console says of the calibrator's solve numbers: they count every solve, and only good
    ones are published, so a number skipped is a solve not kept (refused or failed, in its log)."""

    def __init__(self) -> None:
        self.last: int | None = None

    def note(self, solve: int | None, run_dir: Path, *, resumed: bool = False) -> str:
        """A note for the line of calibration `solve` (None: unnumbered): resumed from the state file (the
        calibrator numbers on from it), or after solves that were not kept; else ''."""
        if solve is None:
            return ""
        first = 1 if self.last is None or solve <= self.last else self.last + 1
        self.last = solve
        if resumed:
            return "  (resumed: the calibrator's state file)"
        if solve <= first:
            return ""
        skipped = f"solve {first}" if solve - first == 1 else f"solves {first}-{solve - 1}"
        return f"  ({skipped} not kept: see {run_dir / 'logs' / 'calibrator.log'})"


REPLAY_TAIL_S = 20.0  # after a replay's last frame, how long its last frame sets may take to be calibrated


def _replay_ended(launch) -> float | None:
    """The time a replay child ended well (then it is no longer a child to check); None while it runs."""
    import time

    for child in launch.exited():
        if child.name == "replay" and child.process.returncode == 0:
            launch.children.remove(child)
            print("replay: the session has been played to its end", flush=True)
            return time.monotonic()
    return None


def rerun_lines(values: list[str]) -> list[str]:
    """What the operator needs of the --rerun sinks the calibrator opens: the web viewer's page to open,
    the file, the viewer it streams to (the calibrator's own lines go to its log)."""
    import socket

    from camnet.viz_sinks import parse_sink

    return [f"rerun: {parse_sink(value).describe(host=socket.gethostname())}" for value in values]


def _network_spec(args: argparse.Namespace, rig_path: Path, rig, run_dir: Path, calibrator_id: str | None = None):
    """The nodes `camnet up` starts; `calibrator_id`: the calibrator's session id (camnet.bus.source)."""
    from camnet.bus.launch import NetworkSpec, bus_flags
    from camnet.bus.session import options_from_args

    return NetworkSpec(
        rig_path=rig_path, rig_name=rig.name,
        cameras=() if args.replay else tuple((e.id, e.driver) for e in rig.cameras),
        bus=tuple(bus_flags(options_from_args(args))),
        driver=("--features", "--detector", str(args.detector)) if args.features else (),
        matcher=("--detector", str(args.detector)),
        calibrator=("--state", str(run_dir / "calibration.json"),
                    "--observations-out", str(run_dir / "observations.json"),
                    *(("--session-id", calibrator_id) if calibrator_id else ()),
                    *(f for v in args.rerun for f in ("--rerun", v)),
                    "--rerun-frame-period-s", repr(args.rerun_frame_period_s)),
        record_path=Path(args.record) if args.record else None)


def run(args: argparse.Namespace) -> int:
    import contextlib
    import threading
    import time

    from camnet.bus import keys
    from camnet.bus.launch import Launch, start_network
    from camnet.bus.node import stop_on_signals
    from camnet.bus.session import joined, options_from_args
    from camnet.bus.source import new_session_id
    from camnet.errors import CamnetError
    from camnet.io.run_dir import default_run_dir

    rig_path, rig = _checked_rig(args)
    run_dir = Path(args.out) if args.out else default_run_dir(rig.name)
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    truth = rig.simulated_truth()
    calibrator_id = new_session_id()
    spec = _network_spec(args, rig_path, rig, run_dir, calibrator_id)
    follower = RunFollower(args, truth, calibrator_id)
    source = f", replaying {args.replay}" if args.replay else ""
    print(f"camnet up: rig {rig.name!r}, {len(rig.cameras)} cameras{source}; results and logs in {run_dir}",
          flush=True)
    with contextlib.ExitStack() as stack:
        # Ctrl-C and a process manager's SIGTERM only ask the loop below to end, so that no
        # exception lands in the middle of starting a node (which would leave it orphaned)
        # and every node is stopped on the way out.
        stop = stack.enter_context(stop_on_signals(threading.Event()))
        progress_file = stack.enter_context(open(args.progress_jsonl, "w")) if args.progress_jsonl else None
        session = stack.enter_context(joined(options_from_args(args)))
        launch = stack.enter_context(Launch(run_dir / "logs", restart=not args.no_restart,
                                            say=lambda line: print(f"camnet up: {line}", flush=True)))
        subscribers = [session.declare_subscriber(keys.calibration(rig.name), follower.on_calibration),
                       launch.watch(session, rig.name)]  # a node is up once its token is seen
        start_network(launch, spec)
        for line in rerun_lines(args.rerun):
            print(line, flush=True)
        if args.replay:
            # Named by no token (it declares one per camera of its session): judged by the clock, and never
            # restarted anyway.
            launch.start("replay", ["replay", str(args.replay), "--rig", rig.name, *spec.bus], restart=False)
        follower.follow(launch, stop, time.monotonic(), run_dir, progress_file)
        _await_state(run_dir / "calibration.json", follower.on_calibration.latest)
        if stop.is_set():
            print("interrupted", flush=True)
        for subscriber in subscribers:
            subscriber.undeclare()
        restarts = launch.restart_counts()
    message = _state(run_dir / "calibration.json")
    if message is None and stop.is_set():
        return 130
    if args.until_frame_sets is not None and follower.reached is None and not stop.is_set():
        last = f"the last was from {message.frame_sets or 0}" if message is not None else "none at all"
        raise CamnetError(f"--until-frame-sets: no calibration from {args.until_frame_sets} frame sets in "
                          f"{args.duration_s:.0f} s ({last}); give a longer --duration-s, or see the nodes' logs "
                          f"in {run_dir / 'logs'}")
    if message is None:
        raise CamnetError(f"no calibration in {args.duration_s:.0f} s; the nodes' logs are in {run_dir / 'logs'}")
    print(_finish(args, run_dir, message, follower, truth, restarts))
    return 0


STATE_WAIT_S = 10.0  # how long the calibrator may take to persist the last calibration it published


def _state(path: Path) -> CalibrationMessage | None:
    """The calibration the calibrator persisted in its state file `path` (None: none yet); CamnetError if
    it is unreadable."""
    from camnet.errors import CamnetError, InputError
    from camnet.io.messages import load_calibration_message

    if not path.exists():
        return None
    try:
        return load_calibration_message(path)
    except InputError as exc:
        raise CamnetError(f"the calibrator's state file cannot be read: {exc}") from exc


def _await_state(path: Path, published: CalibrationMessage | None) -> None:
    """Wait (at most STATE_WAIT_S) until the state file holds the calibrator's calibration `published`:
    it writes it just after publishing it."""
    import time

    from camnet.errors import CamnetError

    if published is None or published.solve is None:
        return
    deadline_s = time.monotonic() + STATE_WAIT_S
    while time.monotonic() < deadline_s:
        try:
            kept = _state(path)
        except CamnetError:  # being replaced: read it again
            kept = None
        if kept is not None and (kept.solve or 0) >= published.solve:
            return
        time.sleep(0.1)


def restarts_line(restarts: dict[str, int]) -> str:
    """The final summary's line on the nodes restarted: which, and how often."""
    if not restarts:
        return "nodes restarted: none"
    return "nodes restarted: " + ", ".join(f"{name} ({n} {'time' if n == 1 else 'times'})"
                                           for name, n in restarts.items())


def _finish(args: argparse.Namespace, run_dir: Path, message: CalibrationMessage, follower: RunFollower,
            truth, restarts: dict[str, int]) -> str:
    """Write the run directory's results of calibration `message`; the final lines: the calibration, the
    files, the next commands."""
    from camnet.commands.up_console import final_report
    from camnet.io.formats import write_json_atomic
    from camnet.io.messages import calibration_message_to_doc
    from camnet.io.run_dir import observations_behind, write_results

    observations = observations_behind(run_dir / "observations.json", message)
    written = write_results(run_dir, message, observations, truth)
    if args.output:
        write_json_atomic(args.output, calibration_message_to_doc(message))
        written.append(Path(args.output))
    lines = [final_report(message.calibration, truth), "", restarts_line(restarts)]
    foreign = follower.on_calibration.foreign.total
    if foreign:
        lines.append(f"calibrations from another publisher than the rig's calibrator: {foreign}, ignored")
    lines += ["", f"files in {run_dir}:"]
    lines += [f"  {p.name + ('/' if p.is_dir() else ''):<20} {_DESCRIBE.get(p.name, '')}".rstrip() for p in written]
    if observations is None:
        lines.append("  (the calibrator stopped without writing the observations behind the last calibration: "
                     "no observations.json)")
    cal_path = run_dir / "calibration.json"
    lines += ["next:", f"  open {run_dir / 'report.html'}",
              f"  camnet export {cal_path} --to kalibr|ros|anipose|colmap-bin -o OUT"]
    if observations is not None:  # solve it again offline: with K given, another --free, ...
        lines.append(f"  camnet calibrate {run_dir / 'observations.json'} -o calibration.json --initial {cal_path}")
    return "\n".join(lines)


_DESCRIBE = {
    "calibration.json": "the last calibration (camnet.calibration/1)",
    "observations.json": "the pooled observations it was solved from (camnet.observations/1)",
    "truth.json": "the simulation's ground truth (camnet report --truth)",
    "report.html": "verdict, errors (against the truth when simulated), uncertainty, layout",
    "calibration.yaml": "OpenCV FileStorage",
    "colmap": "COLMAP text model",
    "points.ply": "the points with their sigmas",
}
