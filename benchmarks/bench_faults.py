#!/usr/bin/env python3
"""Faults on a live simulated network, and what each costs.

A 4-camera sim rig at 30 fps (small images, so that it runs on 2 cores):
drivers, matcher and calibrator as processes meeting at a router, and an
observer that queries the calibration key. A calibration here is any a
solve published, whatever its verdict: a fault asks whether calibrations go
on, and how good they are is the rig's (benchmarks/bench_rigs.py). For each
fault, once the network has published a calibration:

- alive: every node still running (or restarted) afterwards;
- lost: calibrations published before the fault that the network no
  longer answers after it (must be 0: the last one is always answered);
- next s: seconds from the end of the fault to the next calibration
  published (the network calibrates again);
- RSS MB: the nodes' resident memory before and after.

Then the same rig under `camnet up`, whose supervisor restarts a node that
dies: a driver, the matcher and the calibrator killed with SIGKILL in turn,
with the same columns (next s: from the death to the next
calibration solved from frames captured after it).

    python benchmarks/bench_faults.py                # every fault, full length
    python benchmarks/bench_faults.py --short        # the test's version: a few faults, short
    python benchmarks/bench_faults.py --supervised   # only the rows under camnet up
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from camnet.bus import keys
from camnet.bus.launch import Child, Launch, NetworkSpec, start_network
from camnet.bus.session import BusOptions, open_session
from camnet.errors import InputError
from camnet.io.messages import CalibrationMessage, decode_calibration_message
from camnet.testing.ports import free_port

BOX_CENTRE = [0.0625, 0.0, 0.65]


def rig_document(name: str, *, fps: float = 30.0, n_cameras: int = 4, side_px: int = 320) -> dict:
    """The paper's rig at `side_px` wide, with further cameras on an arc beyond four."""
    scale = side_px / 1280
    width, height = side_px, round(1024 * scale)

    def sim(f_px: float, centre, look_at=None) -> dict:
        cam = {"width": width, "height": height, "encoding": "mono8", "fps": fps, "f_px": f_px * scale,
               "cx_px": (width - 1) / 2, "cy_px": (height - 1) / 2, "centre_m": list(centre)}
        return cam | ({"look_at_m": list(look_at)} if look_at is not None else {})

    cameras = [{"id": "left", "driver": "sim", "sim": sim(1500, [0.0, 0.0, 0.0])},
               {"id": "right", "driver": "sim", "sim": sim(1500, [0.125, 0.0, 0.0])},
               {"id": "mono_a", "driver": "sim", "sim": sim(1300, [-0.30, 0.0, 0.05], BOX_CENTRE)},
               {"id": "mono_b", "driver": "sim", "sim": sim(1400, [0.425, 0.0, 0.05], BOX_CENTRE)}]
    for i in range(n_cameras - 4):
        angle = np.deg2rad(-60 + 120 * (i + 0.5) / (n_cameras - 4))
        centre = np.array(BOX_CENTRE) + 0.6 * np.array([np.sin(angle), 0.0, -np.cos(angle)])
        centre[1] += 0.1 if i % 2 else -0.1
        cameras.append({"id": f"mono_{i + 2:02d}", "driver": "sim",
                        "sim": sim(1200 + 80 * i, centre.round(4).tolist(), BOX_CENTRE)})
    return {"rig": name, "stereo": {"left": "left", "right": "right", "baseline_m": 0.125, "parallel": True},
            "scene": {"seed": 7, "box_centre_m": BOX_CENTRE, "box_size_m": [0.10, 0.17, 0.08],
                      "box_rotation_deg_per_s": 20.0},
            "cameras": cameras}


def rss_mb(pid: int) -> float:
    """Resident memory of a process in MB (0 when it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


class Network:
    """A rig's nodes behind a router, an observer of its calibrations, and the faults done to them."""

    def __init__(self, work: Path, rig: dict, *, matcher_flags: tuple[str, ...] = (),
                 calibrator_flags: tuple[str, ...] = ()) -> None:
        self.work = work
        self.rig_name = rig["rig"]
        self.rig_path = work / "rig.yaml"
        self.rig_path.write_text(yaml.safe_dump(rig, sort_keys=False))
        self.state = work / "calibration.json"
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.launch = Launch(work, grace_s=5.0)
        self.matcher_flags = matcher_flags
        self.calibrator_flags = calibrator_flags
        self.calibrations: list[tuple[float, CalibrationMessage]] = []  # (monotonic s, message) as published
        self._lock = threading.Lock()
        self.session = None

    def __enter__(self) -> Network:
        self.launch.__enter__()
        self.started_s = time.monotonic()
        self.start_router()
        self.session = open_session(BusOptions(connect=(self.endpoint,)))
        self.session.declare_subscriber(keys.calibration(self.rig_name), self._on_calibration)
        self.start_nodes(("--connect", self.endpoint))
        return self

    def start_nodes(self, bus: tuple[str, ...], *, drivers: bool = True) -> None:
        """The rig's nodes, joining with `bus` flags: a driver per camera (unless not `drivers`), matcher,
        calibrator."""
        cameras = tuple((c["id"], "sim") for c in yaml.safe_load(self.rig_path.read_text())["cameras"])
        start_network(self.launch, NetworkSpec(
            rig_path=self.rig_path, rig_name=self.rig_name, cameras=cameras if drivers else (), bus=bus,
            matcher=("--publish-period-s", "1.0", *self.matcher_flags),
            calibrator=("--state", str(self.state), *self.calibrator_flags)))

    def __exit__(self, *exc_info: object) -> None:
        try:
            if self.session is not None:
                self.session.close()
        finally:
            self.launch.__exit__(*exc_info)

    def start_router(self) -> Child:
        return self.launch.start("router", ["router", "--listen", self.endpoint], verbose=False)

    def _on_calibration(self, sample) -> None:
        try:
            message = decode_calibration_message(sample.payload.to_bytes())
        except InputError:  # the flood reaches this observer too
            return
        if not message.resumed:  # a restarted calibrator's from its state file was solved before
            with self._lock:
                self.calibrations.append((time.monotonic(), message))

    def child(self, name: str) -> Child:
        return next(c for c in self.launch.children if c.name == name)

    def start_again(self, child: Child) -> Child:
        """Start a stopped `child` again, with its command and flags."""
        command = child.argv[child.argv.index("camnet.cli") + 1:]
        verbose = command[:1] == ["-v"]
        return self.launch.start(child.name, command[1:] if verbose else command, verbose=verbose)

    def solved_after(self, since_s: float) -> float | None:
        with self._lock:
            times = [t for t, _ in self.calibrations if t >= since_s]
        return times[0] if times else None

    def wait_calibration(self, since_s: float, timeout_s: float) -> float | None:
        """Seconds from `since_s` to the first calibration published after it (None: none came)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            got = self.solved_after(since_s)
            if got is not None:
                return got - since_s
            self.check()
            time.sleep(0.2)
        return None

    def check(self) -> None:
        """Raise if a node has exited that should not have."""
        self.launch.check()

    def answered_ns(self, timeout_s: float = 20.0) -> int | None:
        """When the calibration the network answers on its key was solved (None: nobody answers)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for reply in self.session.get(keys.calibration(self.rig_name), timeout=2.0):
                if reply.ok is not None:
                    try:
                        solved_ns = decode_calibration_message(reply.ok.payload.to_bytes()).solved_ns
                    except InputError:
                        continue
                    if solved_ns is not None:
                        return solved_ns
            time.sleep(0.2)
        return None

    def published_ns(self) -> list[int]:
        """When each calibration published so far was solved."""
        with self._lock:
            return [m.solved_ns or 0 for _, m in self.calibrations]

    def rss_mb(self) -> float:
        return sum(rss_mb(c.process.pid) for c in self.launch.children)

    def alive(self) -> bool:
        return not self.launch.exited()


class SupervisedNetwork(Network):
    """The rig under `camnet up` (one process, whose supervisor starts and restarts the nodes), observed the
    same way."""

    def __enter__(self) -> SupervisedNetwork:
        self.started_s = time.monotonic()
        self._log = open(self.work / "up.log", "w")  # noqa: SIM115 (closed in __exit__)
        self.up = subprocess.Popen([sys.executable, "-m", "camnet.cli", "up", str(self.rig_path), "--forever",
                                    "--run-dir", str(self.work / "run"), "--listen", self.endpoint],
                                   stdout=self._log, stderr=subprocess.STDOUT)
        self.session = open_session(BusOptions(connect=(self.endpoint,)))
        self.session.declare_subscriber(keys.calibration(self.rig_name), self._on_calibration)
        return self

    def __exit__(self, *exc_info: object) -> None:
        try:
            if self.session is not None:
                self.session.close()
        finally:
            self.up.send_signal(signal.SIGINT)
            try:
                self.up.wait(timeout=120)
            except subprocess.TimeoutExpired:
                self.up.kill()
                self.up.wait()
            self._log.close()

    def node_pid(self, pattern: str) -> int:
        """The pid of the one node of camnet up whose command line matches `pattern` (`pgrep -f`)."""
        found = subprocess.run(["pgrep", "-P", str(self.up.pid), "-f", pattern], capture_output=True, text=True)
        pids = [int(p) for p in found.stdout.split()]
        if len(pids) != 1:
            raise RuntimeError(f"{len(pids)} nodes of camnet up match {pattern!r}; its log: {self.work / 'up.log'}")
        return pids[0]

    def rss_mb(self) -> float:
        found = subprocess.run(["pgrep", "-P", str(self.up.pid)], capture_output=True, text=True)
        return rss_mb(self.up.pid) + sum(rss_mb(int(p)) for p in found.stdout.split())

    def alive(self) -> bool:
        return self.up.poll() is None

    def check(self) -> None:
        if self.up.poll() is not None:
            raise RuntimeError(f"camnet up exited with status {self.up.returncode}; its output ends:\n"
                               f"{(self.work / 'up.log').read_text()[-3000:]}")

    def solved_after(self, since_s: float) -> float | None:
        """The first calibration published after `since_s` from frames captured after it: the rig
        calibrating again, not a solve already under way."""
        since_ns = time.time_ns() - round((time.monotonic() - since_s) * 1e9)
        with self._lock:
            times = [t for t, m in self.calibrations if t >= since_s and (m.latest_capture_ns or 0) >= since_ns]
        return times[0] if times else None


# The nodes killed under camnet up, and a pattern of their command lines among its children.
SUPERVISED = (("driver-mono_a", r"camnet\.cli -v driver sim .*--camera mono_a( |$)"),
              ("matcher", r"camnet\.cli -v matcher "),
              ("calibrator", r"camnet\.cli -v calibrator "))


def kill_supervised(pattern: str) -> Callable[[Network], str]:
    def fault(net: SupervisedNetwork) -> str:
        os.kill(net.node_pid(pattern), signal.SIGKILL)
        return "kill -9; camnet up restarts it"
    return fault


@dataclass(frozen=True)
class Result:
    fault: str
    alive: bool
    lost: int | None
    next_s: float | None
    rss_before_mb: float
    rss_after_mb: float
    note: str = ""

    def row(self) -> str:
        lost = "?" if self.lost is None else str(self.lost)
        after = "none" if self.next_s is None else f"{self.next_s:.1f}"
        return (f"{self.fault:<36}{'yes' if self.alive else 'NO':>6}{lost:>6}{after:>10}"
                f"{self.rss_before_mb:>9.0f}{self.rss_after_mb:>9.0f}  {self.note}")


HEADER = f"{'fault':<36}{'alive':>6}{'lost':>6}{'next s':>10}{'RSS MB':>9}{'after':>9}  note"


def measure(net: Network, name: str, fault: Callable[[Network], str], *, recover_s: float) -> Result:
    """Do `fault` to a network that already calibrates; what it cost."""
    rss_before = net.rss_mb()
    before_ns = net.published_ns()
    note = fault(net) or ""
    ended_s = time.monotonic()
    next_cal = net.wait_calibration(ended_s, recover_s)
    answered_ns = net.answered_ns()
    # Lost: calibrations from before the fault newer than what the network answers after it.
    lost = None if answered_ns is None else sum(t > answered_ns for t in before_ns)
    return Result(name, net.alive(), lost, next_cal, rss_before, net.rss_mb(), note)


# ------------------------------------------------------------------ the faults

def kill_and_restart(name: str, outage_s: float = 0.0) -> Callable[[Network], str]:
    def fault(net: Network) -> str:
        child = net.child(name)
        net.launch.stop(child, kill=True)
        time.sleep(outage_s)
        net.start_again(child)
        return f"kill -9, {outage_s:.0f} s down"
    return fault


# `camnet status` waits for every live node's statistics, a while beyond its --wait-s; should the
# matcher's still not reach it on a loaded machine, status is asked again while the camera stays
# silent, this many times.
STATUS_TRIES = 4


def silent_camera(camera: str, silent_s: float, *, check_status: bool = False) -> Callable[[Network], str]:
    """Stop a driver (SIGSTOP: its process and session stay, its frames stop) for `silent_s`; the network
    must go on calibrating from the other cameras meanwhile. With `check_status`, `camnet status` must
    show it MISSING (asked up to STATUS_TRIES times; the silence lasts until it is answered)."""
    def fault(net: Network) -> str:
        child = net.child(f"driver-{camera}")
        os.kill(child.process.pid, signal.SIGSTOP)
        started_s = time.monotonic()
        shown, tries = False, 0
        try:
            during = net.wait_calibration(started_s + 2.0, silent_s)
            while check_status and not shown and tries < STATUS_TRIES:
                tries += 1
                shown = any(camera in line and "MISSING" in line for line in run_status(net).splitlines())
            time.sleep(max(0.0, silent_s - (time.monotonic() - started_s)))
        finally:
            os.kill(child.process.pid, signal.SIGCONT)
        missing = ""
        if check_status:
            missing = (f"shown MISSING by status (try {tries})" if shown
                       else f"status did not show it missing in {tries} tries")
        during_text = "none" if during is None else f"{during:.1f} s"
        return f"silent {silent_s:.0f} s; first calibration during it after {during_text} {missing}".strip()
    return fault


def run_status(net: Network) -> str:
    import subprocess

    proc = subprocess.run([sys.executable, "-m", "camnet", "status", "--rig", net.rig_name, "--connect",
                           net.endpoint, "--wait-s", "2.5"], capture_output=True, text=True, timeout=60)
    return proc.stdout + proc.stderr


DAMAGES = {
    "truncated": lambda text: text[: len(text) // 2],
    "not JSON": lambda text: "{not json",
    "binary": lambda text: "\x00\xff" * 100,
    "deep nesting": lambda text: "[" * 100_000,
    "huge integer": lambda text: text.replace('"solve": ', '"solve": 1' + "0" * 5000 + " + ", 1)
    if '"solve": ' in text else "9" * 5000,
    "another rig": lambda text: json.dumps(_scaled(json.loads(text), 4.0)),
    "K not a camera matrix": lambda text: json.dumps(_bad_k(json.loads(text))),
}


def _scaled(doc: dict, factor: float) -> dict:
    for cam in doc["cameras"]:
        cam["t"] = [factor * x for x in cam["t"]]
    return doc


def _bad_k(doc: dict) -> dict:
    doc["cameras"][0]["K"][2] = [0.0, 0.0, 5.0]
    return doc


def damaged_state(how: str) -> Callable[[Network], str]:
    def fault(net: Network) -> str:
        child = net.child("calibrator")
        net.launch.stop(child)
        before = len(list(net.work.glob("calibration.json.*-*")))
        net.state.write_text(DAMAGES[how](net.state.read_text()))
        net.start_again(child)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and len(list(net.work.glob("calibration.json.*-*"))) == before:
            time.sleep(0.2)
        aside = len(list(net.work.glob("calibration.json.*-*"))) > before
        return f"state {how}: {'set aside, not resumed' if aside else 'RESUMED'}"
    return fault


def malformed_flood(n: int) -> Callable[[Network], str]:
    """`n` malformed messages on every key a node reads: frames, observations, calibration, statistics."""
    def fault(net: Network) -> str:
        rng = np.random.default_rng(0)
        rig = net.rig_name
        targets = [keys.frame(rig, "left"), keys.frame(rig, "mono_a"), keys.observations(rig),
                   keys.calibration(rig), keys.node_stats(rig, "driver", "left")]
        publishers = [net.session.declare_publisher(k) for k in targets]
        samples = [b"", b"{", b"[" * 50_000, b"\xff" * 64, b'{"format": "camnet.observations/1", "cameras": 3}',
                   b"CNFR" + bytes(60)]
        for i in range(n):
            for publisher in publishers:
                publisher.put(samples[i % len(samples)] if i % 3 else rng.bytes(int(rng.integers(1, 200))))
            if i % 500 == 0:
                time.sleep(0.05)  # the flood must not drop in Zenoh's queues before it reaches the nodes
        for publisher in publishers:
            publisher.undeclare()
        return f"{n} x {len(targets)} keys"
    return fault


def forged_observations(net: Network) -> str:
    """Observations of another rig (baseline 0.5 m) from a peer that is no matcher: none may become a
    calibration."""
    from camnet.io.formats import observations_to_doc
    from camnet.sim.simulate import make_rig, observe

    doc = observations_to_doc(observe(make_rig(seed=9), seed=9).observations)
    doc["stereo"]["baseline_m"] = 0.5
    publisher = net.session.declare_publisher(keys.observations(net.rig_name))
    for _ in range(15):
        publisher.put(json.dumps(doc).encode())
        time.sleep(0.3)
    publisher.undeclare()
    time.sleep(3.0)
    with net._lock:
        forged = sum(abs(_baseline(m.calibration) - 0.5) < 0.05 for _, m in net.calibrations)
    return f"15 forged messages; {forged} became calibrations"


def _baseline(cal) -> float:
    cams = {c.id: c for c in cal.cameras}
    return float(np.linalg.norm(cams["left"].centre - cams["right"].centre))


def scenarios(short: bool) -> list[tuple[str, Callable[[Network], str]]]:
    if short:
        return [("mono camera silent 8 s", silent_camera("mono_b", 8.0, check_status=True)),
                ("kill -9 calibrator, restart", kill_and_restart("calibrator")),
                ("state file: another rig", damaged_state("another rig")),
                ("1000 malformed messages per key", malformed_flood(1000))]
    found = [(f"kill -9 {n}, restart", kill_and_restart(n)) for n in ("driver-mono_a", "matcher", "calibrator")]
    found += [("kill -9 router, 1 s", kill_and_restart("router", 1.0)),
              ("kill -9 router, 20 s", kill_and_restart("router", 20.0)),
              ("mono camera silent 30 s", silent_camera("mono_b", 30.0, check_status=True))]
    found += [(f"state file: {how}", damaged_state(how)) for how in DAMAGES]
    found += [("10k malformed messages per key", malformed_flood(10_000)),
              ("forged observations (0.5 m)", forged_observations)]
    return found


def run(work: Path, *, short: bool, recover_s: float, out=print) -> list[Result]:
    results = []
    with Network(work, rig_document("faults")) as net:
        first = net.wait_calibration(net.started_s, 180.0)
        if first is None:
            raise RuntimeError(f"no first calibration; logs in {work}")
        out(f"first calibration after {first:.1f} s of the run")
        out(HEADER)
        for name, fault in scenarios(short):
            result = measure(net, name, fault, recover_s=recover_s)
            out(result.row())
            results.append(result)
    return results


def run_supervised(work: Path, *, recover_s: float, out=print) -> list[Result]:
    results = []
    with SupervisedNetwork(work, rig_document("supervised")) as net:
        first = net.wait_calibration(net.started_s, 180.0)
        if first is None:
            raise RuntimeError(f"no first calibration under camnet up; its output ends:\n"
                               f"{(work / 'up.log').read_text()[-3000:]}")
        out(f"under camnet up: first calibration after {first:.1f} s of the run")
        out(HEADER)
        for name, pattern in SUPERVISED:
            net.wait_calibration(time.monotonic(), recover_s)  # calibrating again since the fault before
            result = measure(net, f"camnet up: kill -9 {name}", kill_supervised(pattern), recover_s=recover_s)
            out(result.row())
            results.append(result)
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--short", action="store_true", help="the few short faults the tests run")
    parser.add_argument("--recover-s", type=float, default=90.0, help="longest wait for the next calibration")
    parser.add_argument("--supervised", action="store_true", help="only the rows under camnet up")
    args = parser.parse_args()
    results = []
    if not args.supervised:
        with tempfile.TemporaryDirectory(prefix="camnet-bench-faults-") as tmp:
            results += run(Path(tmp), short=args.short, recover_s=args.recover_s)
    if not args.short:
        with tempfile.TemporaryDirectory(prefix="camnet-bench-faults-up-") as tmp:
            results += run_supervised(Path(tmp), recover_s=args.recover_s)
    return 0 if all(r.alive and r.lost == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
