"""Starting camnet nodes as child processes on one machine, supervising them, and always stopping them.

Each node is `python -m camnet.cli <command> ...` with its log in its own
file. `Launch` is a context manager: leaving it (normally, on an error or on
Ctrl-C) stops every child with SIGTERM, then SIGKILL after a grace period.
A child is up once the liveliness token it declares when it serves (`token`,
`camnet.bus.keys.node`) has been seen (`watch`). With `restart`, `check`
restarts a node that exits after it came up, after a back-off, up to
`RESTARTS_PER_MINUTE` times a minute; one that exits before it was ever up
failed to start, and ends the run; without `restart`, any exit ends the run.
`start_network` starts the nodes of one rig (`NetworkSpec`) in it, giving its
v4l2 drivers one start instant for their files (drivers/v4l2.py).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from camnet.bus import keys
from camnet.bus.session import BusOptions
from camnet.errors import CamnetError

log = logging.getLogger(__name__)


# Only for a child that names no token, or a Launch that watches none: such a child counts as up once it has run
# this long. Generous, as a loaded machine can take many seconds just to import and connect a node. Also the
# longest a child still starting is waited for when a sibling fails to start.
STARTUP_S = 30.0
RESTART_DELAY_S = 1.0  # a node's first restart waits this long, each further one within a minute twice as long
MAX_RESTART_DELAY_S = 10.0
RESTARTS_PER_MINUTE = 5  # a node that exits more often is broken, not unlucky: the run ends


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    process: subprocess.Popen
    started_mono_s: float = 0.0
    command: tuple[str, ...] = ()  # what `Launch.start` was given, to start it again
    verbose: bool = True
    restart: bool = True  # restarted when it exits, under a Launch that restarts
    restarted: bool = False  # a restart itself: the node came up once, so an exit before it is up again is no
    # failure to start (a camera host rebooting), and only the limit a minute ends its restarts
    token: str | None = None  # the liveliness key it declares once it serves (camnet.bus.keys.node)

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def why(self) -> str:
        """One line: how it ended, and its own error line (`camnet ...: error: ...`) when it printed one."""
        ended = f"{self.name} {exit_words(self.process.returncode)}"
        errors = [line for line in self.log_tail(40).splitlines() if line.startswith("camnet ") and ": error: " in line]
        return f"{ended}: {errors[-1].split(': error: ', 1)[1]}" if errors else ended


def exit_words(returncode: int) -> str:
    """How a process ended, in words: 'exited with status 2', 'was killed by signal 9 (SIGKILL)'."""
    if returncode >= 0:
        return f"exited with status {returncode}"
    try:
        name = f" ({signal.Signals(-returncode).name})"
    except ValueError:
        name = ""
    return f"was killed by signal {-returncode}{name}"


def bus_flags(options: BusOptions) -> list[str]:
    """Bus flags for children of a node with these bus `options`.

    Children connect to what the parent listens on (a wildcard address
    becomes loopback) and to what it connects to; with no endpoints at all
    everyone meets at the default loopback rendezvous. On a secured rig
    (`options.secure`) each child joins the router with its own identity.
    """
    flags: list[str] = ["--secure", options.secure] if options.secure else []
    for endpoint in options.listen:
        flags += ["--connect", endpoint.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]")]
    for endpoint in options.connect:
        flags += ["--connect", endpoint]
    if options.zenoh_config:
        flags += ["--zenoh-config", options.zenoh_config]
    if options.scouting:
        flags.append("--scouting")
    return flags


# A stopping calibrator ends its solve, writes the observations behind its last calibration and flushes its
# Rerun recording: on a loaded machine that takes more than 10 s.
STOP_GRACE_S = 20.0


class Launch:
    def __init__(self, log_dir: Path, *, grace_s: float = STOP_GRACE_S, restart: bool = False,
                 say: Callable[[str], None] | None = None) -> None:
        """`say`: where a restart is told besides the node's log (default: this module's log)."""
        self.log_dir = Path(log_dir)
        self.grace_s = grace_s
        self.restart = restart
        self.say = say or (lambda line: log.warning("%s", line))
        self.children: list[Child] = []
        self.restarts: dict[str, list[float]] = {}  # node name -> when each of its restarts was decided
        self._due: list[tuple[float, Child]] = []  # exited children to start again, and when
        self._watching = False
        self._appeared: dict[str, float] = {}  # liveliness key -> when its latest token appeared (monotonic s)
        self._lock = threading.Lock()  # tokens arrive on Zenoh's threads

    def __enter__(self) -> Launch:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop_all()

    def watch(self, session, rig: str):
        """Judge the children of `rig` that name a `token` by it, from now on: watch the node tokens on
        `session`. The liveliness subscriber (undeclare it, or close the session, to stop)."""
        self._watching = True
        return session.liveliness().declare_subscriber(keys.all_nodes(rig), self._on_token, history=True)

    def _on_token(self, sample) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self._appeared[str(sample.key_expr)] = time.monotonic()

    def start(self, name: str, command: list[str], *, verbose: bool = True, restart: bool = True,
              token: str | None = None) -> Child:
        """Start node `name`; with `restart` (and a Launch that restarts), it is started again when it exits
        after it came up; `token`: the liveliness key by which it is known to be up (see `watch`)."""
        argv = [sys.executable, "-m", "camnet.cli", *(["-v"] if verbose else []), *command]
        log_path = self.log_dir / f"{name}.log"
        started_s = time.monotonic()  # before the process: no token of its can have appeared earlier
        with open(log_path, "ab") as out:
            process = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                       start_new_session=True)
        child = Child(name, argv, log_path, process, started_s, tuple(command), verbose, restart, token=token)
        self.children.append(child)
        log.info("started %s (pid %d): %s", name, process.pid, " ".join(command))
        return child

    def restart_counts(self) -> dict[str, int]:
        """How often each restarted node was restarted, in the order of their first restart."""
        return {name: len(times) for name, times in self.restarts.items()}

    def is_up(self, child: Child) -> bool:
        """Whether `child` has come up: its token has appeared since its start. A child that names no token,
        or under a Launch that watches none, has only the clock to go by: up once it has run `STARTUP_S`."""
        if child.token is not None and self._watching:
            with self._lock:
                appeared_s = self._appeared.get(child.token)
            return appeared_s is not None and appeared_s >= child.started_mono_s
        return time.monotonic() - child.started_mono_s >= STARTUP_S

    def _starting(self, child: Child) -> bool:
        """Whether `child` is still starting: running, not up, and within `STARTUP_S` of its start."""
        return (child.process.poll() is None and not self.is_up(child)
                and time.monotonic() - child.started_mono_s < STARTUP_S)

    def _restartable(self, child: Child) -> bool:
        """Whether `child`, ended, is to be started again: it came up (a node that fails before it is up, as
        a camera that is not there, fails again), and its restarts this minute are within the limit."""
        if not (self.restart and child.restart):
            return False
        if not (child.restarted or self.is_up(child)):
            return False
        return len(self._recent_restarts(child.name)) < RESTARTS_PER_MINUTE

    def _recent_restarts(self, name: str) -> list[float]:
        now_s = time.monotonic()
        return [t for t in self.restarts.get(name, []) if now_s - t < 60.0]

    def _schedule_restart(self, child: Child) -> None:
        recent = len(self._recent_restarts(child.name))
        delay_s = min(MAX_RESTART_DELAY_S, RESTART_DELAY_S * 2 ** recent)
        self.restarts.setdefault(child.name, []).append(time.monotonic())
        line = f"{child.why()}; restarting it in {delay_s:g} s, restart {len(self.restarts[child.name])}"
        self.say(line)
        try:
            with open(child.log_path, "a") as out:
                out.write(f"supervisor: {line}\n")
        except OSError:
            pass
        self.children.remove(child)
        self._due.append((time.monotonic() + delay_s, child))

    def _start_due(self) -> None:
        now_s = time.monotonic()
        for due in [d for d in self._due if d[0] <= now_s]:
            self._due.remove(due)
            old = due[1]
            self.start(old.name, list(old.command), verbose=old.verbose, restart=old.restart,
                       token=old.token).restarted = True

    def exited(self) -> list[Child]:
        """Children that have ended."""
        return [c for c in self.children if c.process.poll() is not None]

    def check(self) -> None:
        """Restart the children that have ended and may be (`restart`), start those whose back-off is over,
        and raise CamnetError naming every other child that has ended, with its error line.

        When one fails before it is up, its siblings still starting (cameras
        of one rig often fail together: unplugged, wrong ids) are given until
        they are up, or at most `STARTUP_S` after their start, so that all of
        them are named at once. A node restarted more than
        `RESTARTS_PER_MINUTE` times a minute ends the run so too.
        """
        for child in self.exited():
            if self._restartable(child):
                self._schedule_restart(child)
        self._start_due()
        exited = self.exited()
        if not exited:
            return
        if any(c.process.returncode != 0 for c in exited):
            while any(self._starting(c) for c in self.children if c not in exited):
                time.sleep(0.1)
            exited = self.exited()
        if len(exited) == 1:
            child = exited[0]
            again = len(self._recent_restarts(child.name))
            often = f" after {again} restarts within a minute" if again >= RESTARTS_PER_MINUTE else ""
            raise CamnetError(f"node {child.why()}{often}; the end of {child.log_path}:\n{child.log_tail()}")
        lines = [f"{len(exited)} of {len(self.children)} nodes exited:", *(f"  {c.why()}" for c in exited),
                 f"their logs are in {self.log_dir}"]
        raise CamnetError("\n".join(lines))

    def stop(self, child: Child, *, kill: bool = False) -> int:
        """Stop one child (SIGKILL at once with `kill`); its exit status."""
        if child.process.poll() is None:
            child.process.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
            try:
                child.process.wait(timeout=self.grace_s)
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in %.0f s: killing it", child.name, self.grace_s)
                os.killpg(child.process.pid, signal.SIGKILL)
                child.process.wait()
        if child in self.children:
            self.children.remove(child)
        return child.process.returncode

    def stop_all(self) -> None:
        for child in self.children:
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.grace_s
        for child in list(self.children):
            try:
                child.process.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in %.0f s: killing it", child.name, self.grace_s)
                os.killpg(child.process.pid, signal.SIGKILL)
                child.process.wait()
        self.children.clear()


@dataclass(frozen=True)
class NetworkSpec:
    """The nodes of one rig on this machine: a driver per camera, the matcher, the calibrator, and
    the recorder when `record_path` is given. `bus` flags go to every node, `driver` flags to every
    driver, the others to one node."""

    rig_path: Path
    rig_name: str
    cameras: tuple[tuple[str, str], ...]  # (camera id, driver name), in the rig file's order
    bus: tuple[str, ...] = ()
    driver: tuple[str, ...] = ()
    matcher: tuple[str, ...] = ()
    calibrator: tuple[str, ...] = ()
    record_path: Path | None = None
    # When frame 0 of the rig's v4l2 files is due (Unix epoch ns), given to every v4l2 driver so that they play
    # in step (drivers/v4l2.py); None: the instant `start_network` starts them.
    files_start_ns: int | None = None


def start_network(launch: Launch, spec: NetworkSpec) -> None:
    """Start the nodes of `spec` as children of `launch`, drivers first, each naming the token it declares
    once it serves (kind and id as its `camnet.bus.node.Presence` states them: a driver's id is its camera's)."""
    rig = str(spec.rig_path)

    def token(kind: str, node_id: str) -> str:
        return keys.node(spec.rig_name, kind, node_id)

    # One start for the files of every driver, a restarted one too (it is started with the same command).
    files_start_ns = time.time_ns() if spec.files_start_ns is None else spec.files_start_ns
    files_start = ["--files-start-ns", str(files_start_ns)]
    for camera_id, driver in spec.cameras:
        files = files_start if driver == "v4l2" else []
        launch.start(f"driver-{camera_id}", ["driver", driver, "--rig", rig, "--camera", camera_id, *files,
                                             *spec.driver, *spec.bus], token=token("driver", camera_id))
    launch.start("matcher", ["matcher", "--rig", rig, *spec.matcher, *spec.bus], token=token("matcher", "matcher"))
    launch.start("calibrator", ["calibrator", "--rig", rig, *spec.calibrator, *spec.bus],
                 token=token("calibrator", "calibrator"))
    if spec.record_path is not None:
        # Not restarted: a session file is never overwritten, so a second recorder could only fail.
        launch.start("recorder", ["record", "--rig", spec.rig_name, "-o", str(spec.record_path), *spec.bus],
                     restart=False, token=token("recorder", "recorder"))
