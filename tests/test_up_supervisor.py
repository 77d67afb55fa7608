"""`camnet up` as a supervisor: a node killed with SIGKILL is restarted, and the run ends with its calibration.

Real processes on a loopback port of the test's own; the waits are on progress (calibrations, the nodes'
logs), not on fixed times.
"""

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from camnet.bus import keys
from camnet.bus import launch as launch_module
from camnet.bus.session import BusOptions, open_session
from camnet.errors import CamnetError
from camnet.io.formats import parse_calibration
from camnet.io.rig import load_rig
from camnet.model.accuracy import compare_cameras, scale_sigma_rel
from tests.conftest import free_port, logs_written, stop_process, wait_for
from tests.test_network import rig_file

WAIT_S = 120  # with no progress at all (no calibration, no line logged), a wait has failed
LIMIT_S = 300  # nor does a wait go on past this, progress or not
# The nodes killed in turn, and a pattern of their command lines (`pgrep -f`) among camnet up's children.
KILLED = (("driver-mono_a", r"camnet\.cli -v driver sim .*--camera mono_a( |$)"),
          ("matcher", r"camnet\.cli -v matcher "),
          ("calibrator", r"camnet\.cli -v calibrator "))


class Output:
    """The lines a process prints, read as they come (a full pipe would stall it)."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line.rstrip("\n"))

    def text(self) -> str:
        return "\n".join(self.lines)

    def join(self) -> None:
        self._thread.join(timeout=30)


def child_pid(parent: int, pattern: str) -> int:
    """The pid of the one child of `parent` whose command line matches `pattern`."""
    found = subprocess.run(["pgrep", "-P", str(parent), "-f", pattern], capture_output=True, text=True)
    pids = [int(p) for p in found.stdout.split()]
    assert len(pids) == 1, (pattern, found.stdout, found.stderr)
    return pids[0]


def solves(progress: Path) -> list[dict]:
    """The calibrations camnet up has shown so far (its --progress-jsonl)."""
    try:
        return [json.loads(line) for line in progress.read_text().splitlines() if line.endswith("}")]
    except FileNotFoundError:
        return []


def test_up_restarts_a_killed_driver_matcher_and_calibrator_and_ends_with_a_calibration_to_scale(tmp_path):
    rig_path = rig_file(tmp_path, 4)
    run_dir, progress = tmp_path / "run", tmp_path / "progress.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "up", rig_path, "--forever", "--run-dir", str(run_dir),
         "--progress-jsonl", str(progress), "--listen", f"tcp/127.0.0.1:{free_port()}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = Output(proc.stdout), Output(proc.stderr)

    def moving() -> tuple[int, int]:
        return len(solves(progress)), logs_written(run_dir)

    def failed(what: str) -> str:
        logs = "\n".join(p.read_text()[-1500:] for p in run_dir.rglob("*.log"))
        return f"{what}\n{stdout.text()}\n{stderr.text()}\n{logs}"

    try:
        for name, pattern in KILLED:
            before = solves(progress)
            last = max((s["solve"] for s in before), default=0)
            # A new solve (after a calibrator's restart, its resumed calibration is not one) since the last kill.
            assert wait_for(lambda last=last: any(s["solve"] > last for s in solves(progress)), WAIT_S,
                            progress=moving, limit_s=LIMIT_S), failed(f"no calibration before killing {name}")
            # At once: a node is up once its token is seen, however soon after its start it is killed.
            os.kill(child_pid(proc.pid, pattern), signal.SIGKILL)
            told = f"{name} was killed by signal 9 (SIGKILL); restarting it in 1 s, restart 1"
            wait_for(lambda told=told: told in stdout.text() or proc.poll() is not None, WAIT_S)
            assert told in stdout.text(), failed(f"{name}'s restart was not told")
        # The restarted calibrator resumes, then solves anew (not a solve its killed self had under way).
        resumes = run_dir / "logs" / "calibrator.log"
        assert wait_for(lambda: "resumed from" in resumes.read_text(), WAIT_S, progress=moving,
                        limit_s=LIMIT_S), failed("the calibrator did not resume")
        # The matcher restarted after the driver: what it pools of mono_a comes from the driver's restart.
        last = max(s["solve"] for s in solves(progress))
        assert wait_for(lambda: any(s["solve"] > last for s in solves(progress)), WAIT_S, progress=moving,
                        limit_s=LIMIT_S), \
            failed("no calibration after the calibrator's restart")
    finally:
        stop_process(proc, first_signal=signal.SIGINT)
        stdout.join()
        stderr.join()
    assert proc.returncode == 0, failed("camnet up did not end well")
    assert "nodes restarted: driver-mono_a (1 time), matcher (1 time), calibrator (1 time)" in stdout.text(), \
        failed("the summary does not name the restarts")
    for name, _ in KILLED:
        log = (run_dir / "logs" / f"{name}.log").read_text()
        assert f"supervisor: {name} was killed by signal 9 (SIGKILL); restarting it in 1 s, restart 1" in log
    calibrator_log = (run_dir / "logs" / "calibrator.log").read_text()
    assert f"resumed from {run_dir / 'calibration.json'}" in calibrator_log, calibrator_log[-3000:]
    cal = parse_calibration(json.loads((run_dir / "calibration.json").read_text()))
    truth = load_rig(rig_path).simulated_truth()
    assert len(cal.cameras) == 4, failed("a camera (the restarted driver's?) is missing from the final calibration")
    scale_error = compare_cameras(cal, truth).scale_rel
    assert abs(scale_error) < 3 * scale_sigma_rel(cal), failed(f"scale off by {scale_error:+.3%}")
    assert solved_from_is_kept(run_dir), failed("the observations behind the final calibration are not kept")


def solved_from_is_kept(run_dir) -> bool:
    """Whether the run directory holds the observations its final calibration was solved from."""
    from camnet.io.messages import load_calibration_message
    from camnet.io.run_dir import observations_behind

    return observations_behind(run_dir / "observations.json",
                               load_calibration_message(run_dir / "calibration.json")) is not None


def forge(doc: dict, factor: float) -> bytes:
    """A well-formed calibration message of the rig: `doc`'s, every length times `factor`, claiming a solve
    and frame sets the calibrator has not reached."""
    forged = {**doc, "solve": 1231, "frame_sets": 999_999, "status": "good"}
    forged["cameras"] = [{**cam, "t": [factor * x for x in cam["t"]]} for cam in doc["cameras"]]
    forged["points"] = [{**p, "xyz": [factor * x for x in p["xyz"]]} for p in doc["points"]]
    return json.dumps(forged).encode()


def test_up_ignores_calibrations_of_another_publisher_and_ends_with_its_calibrators_own(tmp_path):
    from mcap.reader import make_reader

    from camnet.bus.source import SourcedPublisher
    from camnet.io.messages import decode_calibration_message
    from tests.test_foreign_features import Stranger

    rig_path = rig_file(tmp_path, 4)
    rig = load_rig(rig_path)
    truth = rig.simulated_truth()
    run_dir, out, endpoint = tmp_path / "run", tmp_path / "out.json", f"tcp/127.0.0.1:{free_port()}"
    session_path = tmp_path / "session.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "up", rig_path, "--until-frame-sets", "8", "--duration-s", "300",
         "--run-dir", str(run_dir), "-o", str(out), "--listen", endpoint, "--record", str(session_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = Output(proc.stdout), Output(proc.stderr)
    forged: list[bytes] = []
    stranger = None
    with open_session(BusOptions(connect=(endpoint,))) as peer:
        # Stating no source, and stating the peer's own.
        publishers = [peer.declare_publisher(keys.calibration(rig.name))]
        publishers.append(SourcedPublisher(peer.declare_publisher(keys.calibration(rig.name))))
        try:
            # Well-formed features of mono_a, which has no feature stage, for the whole run: its frames must
            # still be matched.
            stranger = Stranger({"mono_a": SourcedPublisher(peer.declare_publisher(keys.features(rig.name,
                                                                                               "mono_a")))})
            # From the calibrator's first calibration to the run's end: a copy 6% too large, four times a second.
            state = run_dir / "calibration.json"
            wait_for(lambda: state.exists() or proc.poll() is not None, WAIT_S,
                     progress=lambda: logs_written(run_dir), limit_s=LIMIT_S)
            if state.exists():
                forged.append(forge(json.loads(state.read_text()), 1.06))
            while forged and proc.poll() is None:
                publishers[len(forged) % 2].put(forged[0])
                forged.append(forged[0])
                wait_for(lambda: proc.poll() is not None, 0.25)
        finally:
            if stranger is not None:
                stranger.close()
            stop_process(proc, first_signal=signal.SIGINT)
            stdout.join()
            stderr.join()
    assert proc.returncode == 0, f"{stdout.text()}\n{stderr.text()}"
    assert stranger.sent >= 2
    assert "ignoring features of camera 'mono_a'" in (run_dir / "logs" / "matcher.log").read_text()
    published = len(forged) - 1
    assert published >= 2, stdout.text()
    # The forgery is a calibration, and a wrong one.
    assert abs(compare_cameras(decode_calibration_message(forged[0]).calibration, truth).scale_rel - 0.06) < 0.01
    assert " solve 1231 " not in stdout.text(), stdout.text()
    ignored = [line for line in stdout.lines if line.startswith("calibrations from another publisher")]
    assert len(ignored) == 1, stdout.text()
    count = int(ignored[0].split(": ")[1].split(",")[0])
    assert 1 <= count <= published, (ignored, published)
    for path in (out, run_dir / "calibration.json"):
        doc = json.loads(path.read_text())
        assert doc["solve"] != 1231 and doc["frame_sets"] >= 8, path
        cal = parse_calibration(doc)
        assert {c.id for c in cal.cameras} == {c.id for c in truth}, path  # mono_a's frames matched throughout
        scale_error = compare_cameras(cal, truth).scale_rel
        assert abs(scale_error) < 3 * scale_sigma_rel(cal), f"{path}: scale off by {scale_error:+.3%}"
    assert solved_from_is_kept(run_dir), stdout.text()
    # The matcher chose its pairs from the calibrator's calibrations only, and the recording holds only those.
    for node in ("matcher", "recorder"):
        log = (run_dir / "logs" / f"{node}.log").read_text()
        assert "ignoring a calibration that is not the rig's calibrator's" in log, log[-3000:]
    with open(session_path, "rb") as stream:
        recorded = [json.loads(message.data) for _, channel, message in make_reader(stream).iter_messages()
                    if channel.topic == keys.calibration(rig.name)]
    assert recorded and all(doc["solve"] != 1231 for doc in recorded), [doc["solve"] for doc in recorded]


def test_a_node_that_keeps_exiting_ends_the_run_past_the_restarts_a_minute_allows(tmp_path, monkeypatch):
    """Restarted with back-off until the limit a minute, then the run ends naming it and its own error."""
    # Shortened, so that the test takes seconds: a node that names no token is judged by the clock, and with
    # none left it counts as one that came up however soon it fails; the limit is two restarts.
    monkeypatch.setattr(launch_module, "STARTUP_S", 0.0)
    monkeypatch.setattr(launch_module, "RESTART_DELAY_S", 0.05)
    monkeypatch.setattr(launch_module, "RESTARTS_PER_MINUTE", 2)
    told: list[str] = []
    with launch_module.Launch(tmp_path, restart=True, say=told.append) as launch:
        launch.start("calibrator", ["calibrator", "--rig", "not*a*rig"])
        with pytest.raises(CamnetError) as raised:
            assert wait_for(lambda: launch.check() and False, 120)
    limit = launch_module.RESTARTS_PER_MINUTE
    assert launch.restart_counts() == {"calibrator": limit}
    # The back-off: doubling from the first delay.
    assert [line.rsplit("; ", 1)[1] for line in told] == [f"restarting it in {0.05 * 2 ** i:g} s, restart {i + 1}"
                                                          for i in range(limit)]
    assert str(raised.value).startswith("node calibrator exited with status 2: --rig: ")
    assert f"after {limit} restarts within a minute" in str(raised.value).splitlines()[0]
    assert (tmp_path / "calibrator.log").read_text().count("supervisor: calibrator exited with status 2") == limit


def test_a_node_killed_as_soon_as_it_is_up_is_restarted(tmp_path, monkeypatch):
    """Up is its token seen, not a time since its start: with a clock that would take any exit within ten
    minutes for a failure to start, a calibrator killed the moment its token is seen is restarted, and comes up
    again."""
    monkeypatch.setattr(launch_module, "STARTUP_S", 600.0)
    monkeypatch.setattr(launch_module, "RESTART_DELAY_S", 0.05)
    rig_path = rig_file(tmp_path, 4)
    rig_name = load_rig(rig_path).name
    endpoint, logs = f"tcp/127.0.0.1:{free_port()}", tmp_path / "logs"
    logs.mkdir()
    told: list[str] = []
    with open_session(BusOptions(listen=(endpoint,))) as session, \
            launch_module.Launch(logs, restart=True, say=told.append) as launch:
        launch.watch(session, rig_name)
        first = launch.start("calibrator", ["calibrator", "--rig", rig_path, "--no-state", "--connect", endpoint],
                             token=keys.node(rig_name, "calibrator", "calibrator"))
        wait_for(lambda: launch.is_up(first) or first.process.poll() is not None, WAIT_S,
                 progress=lambda: logs_written(logs), limit_s=LIMIT_S)
        assert launch.is_up(first), first.log_tail()
        first.process.kill()
        first.process.wait()

        def up_again() -> bool:
            launch.check()  # raises if the kill is taken for a failure to start
            return any(c is not first and launch.is_up(c) for c in launch.children)

        assert wait_for(up_again, WAIT_S, progress=lambda: logs_written(logs), limit_s=LIMIT_S), \
            (logs / "calibrator.log").read_text()[-3000:]
    assert told == ["calibrator was killed by signal 9 (SIGKILL); restarting it in 0.05 s, restart 1"]
    assert launch.restart_counts() == {"calibrator": 1}


def test_a_node_that_exits_before_it_is_up_ends_the_run_naming_it_however_long_it_ran(tmp_path, monkeypatch):
    """A driver that never declared its token failed to start: not restarted, the run ends naming it and its
    error, even where the clock (none left here) would take it for one that came up."""
    monkeypatch.setattr(launch_module, "STARTUP_S", 0.0)
    monkeypatch.setattr(launch_module, "RESTART_DELAY_S", 0.05)
    rig_path = rig_file(tmp_path, 4)
    rig_name = load_rig(rig_path).name
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    told: list[str] = []
    with open_session(BusOptions(listen=(endpoint,))) as session, \
            launch_module.Launch(tmp_path, restart=True, say=told.append) as launch:
        launch.watch(session, rig_name)
        for camera_id in ("nope", "mono_a"):
            launch.start(f"driver-{camera_id}", ["driver", "sim", "--rig", rig_path, "--camera", camera_id,
                                                 "--connect", endpoint],
                         token=keys.node(rig_name, "driver", camera_id))
        with pytest.raises(CamnetError) as raised:
            wait_for(lambda: launch.check() and False, WAIT_S, progress=lambda: logs_written(tmp_path),
                     limit_s=LIMIT_S)
    assert str(raised.value).startswith("node driver-nope exited with status 2: "
                                        f"{rig_path}: no camera 'nope' in rig"), str(raised.value)
    assert told == [] and launch.restart_counts() == {}


def test_on_a_secured_rig_camnet_ups_nodes_are_seen_up_through_the_access_control(tmp_path):
    """camnet up joins a secured rig as an observer: the router's access control lets it see its nodes' tokens,
    else every exit would be taken for a failure to start."""
    import shutil

    from camnet.bus.security import COMMAND_IDENTITY
    from tests.test_security import camnet, router_process

    if shutil.which("openssl") is None:
        pytest.skip("camnet secure init needs the openssl CLI")
    rig_path = rig_file(tmp_path, 4)
    rig_name = load_rig(rig_path).name
    secrets, logs = tmp_path / "secrets", tmp_path / "logs"
    logs.mkdir()
    done = camnet("secure", "init", str(secrets), "--rig", rig_path)
    assert done.returncode == 0, done.stderr
    with router_process(secrets, tmp_path / "router.log") as (endpoint, _), \
            open_session(BusOptions(secure=str(secrets), identity=COMMAND_IDENTITY["up"],
                                    connect=(endpoint,))) as session, \
            launch_module.Launch(logs, restart=True) as launch:
        launch.watch(session, rig_name)
        bus = ["--secure", str(secrets), "--connect", endpoint]
        children = [launch.start("driver-left", ["driver", "sim", "--rig", rig_path, "--camera", "left", *bus],
                                 token=keys.node(rig_name, "driver", "left")),
                    launch.start("calibrator", ["calibrator", "--rig", rig_path, "--no-state", *bus],
                                 token=keys.node(rig_name, "calibrator", "calibrator"))]
        # check() raises if one has exited.
        assert wait_for(lambda: launch.check() or all(launch.is_up(c) for c in children), WAIT_S,
                        progress=lambda: logs_written(logs), limit_s=LIMIT_S), \
            "\n".join(c.log_tail() for c in children)
