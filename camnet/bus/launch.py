"""Starting camnet nodes as child processes on one machine, and always stopping them.

Each node is `python -m camnet.cli <command> ...` with its log in its own
file. `Launch` is a context manager: leaving it (normally, on an error or on
Ctrl-C) stops every child with SIGTERM, then SIGKILL after a grace period.
`start_network` starts the nodes of one rig (`NetworkSpec`) in it.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from camnet.bus.session import BusOptions
from camnet.errors import CamnetError

log = logging.getLogger(__name__)


STARTUP_S = 5.0  # a node that fails this soon after its start is failing to start, as its siblings may be


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    process: subprocess.Popen
    started_mono_s: float = 0.0

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def why(self) -> str:
        """One line: how it ended, and its own error line (`camnet ...: error: ...`) when it printed one."""
        ended = f"{self.name} exited with status {self.process.returncode}"
        errors = [line for line in self.log_tail(40).splitlines() if line.startswith("camnet ") and ": error: " in line]
        return f"{ended}: {errors[-1].split(': error: ', 1)[1]}" if errors else ended


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


class Launch:
    def __init__(self, log_dir: Path, *, grace_s: float = 10.0) -> None:
        self.log_dir = Path(log_dir)
        self.grace_s = grace_s
        self.children: list[Child] = []

    def __enter__(self) -> Launch:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop_all()

    def start(self, name: str, command: list[str], *, verbose: bool = True) -> Child:
        argv = [sys.executable, "-m", "camnet.cli", *(["-v"] if verbose else []), *command]
        log_path = self.log_dir / f"{name}.log"
        with open(log_path, "ab") as out:
            process = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                       start_new_session=True)
        child = Child(name, argv, log_path, process, time.monotonic())
        self.children.append(child)
        log.info("started %s (pid %d): %s", name, process.pid, " ".join(command))
        return child

    def exited(self) -> list[Child]:
        """Children that have ended."""
        return [c for c in self.children if c.process.poll() is not None]

    def check(self) -> None:
        """Raise CamnetError naming every child that has ended, with its error line.

        When one fails at start, its siblings still starting (cameras of one
        rig often fail together: unplugged, wrong ids) are given until
        `STARTUP_S` after their start, so that all of them are named at once.
        """
        exited = self.exited()
        if not exited:
            return
        if any(c.process.returncode != 0 for c in exited):
            starting = [c for c in self.children if c not in exited]
            deadline = max((c.started_mono_s + STARTUP_S for c in starting), default=0.0)
            while time.monotonic() < deadline and any(c.process.poll() is None for c in starting):
                time.sleep(0.1)
            exited = self.exited()
        if len(exited) == 1:
            child = exited[0]
            raise CamnetError(f"node {child.why()}; the end of {child.log_path}:\n{child.log_tail()}")
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


def start_network(launch: Launch, spec: NetworkSpec) -> None:
    """Start the nodes of `spec` as children of `launch`, drivers first."""
    rig = str(spec.rig_path)
    for camera_id, driver in spec.cameras:
        launch.start(f"driver-{camera_id}", ["driver", driver, "--rig", rig, "--camera", camera_id, *spec.driver,
                                                     *spec.bus])
    launch.start("matcher", ["matcher", "--rig", rig, *spec.matcher, *spec.bus])
    launch.start("calibrator", ["calibrator", "--rig", rig, *spec.calibrator, *spec.bus])
    if spec.record_path is not None:
        launch.start("recorder", ["record", "--rig", spec.rig_name, "-o", str(spec.record_path), *spec.bus])
