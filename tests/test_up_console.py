"""What `camnet up` prints: every calibration, numbered as the calibrator publishes it, and where to
watch it in Rerun."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from camnet.bus import keys
from camnet.bus.source import new_session_id
from camnet.cli import build_parser
from camnet.commands.calibrator import FRAME_PERIOD_S
from camnet.commands.up import LatestCalibration, SolveNumbering, _network_spec
from camnet.io.formats import calibration_to_doc
from camnet.io.rig import load_rig
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from tests.conftest import free_port, matched_publisher, wait_for
from tests.test_network import rig_file
from tests.test_web_viewer import stop, wait_for_line

ROOT = Path(__file__).resolve().parent.parent


def test_two_calibrations_in_quick_succession_are_both_shown(zenoh_pair):
    """Both are kept: a console that looks after the second arrived still shows the first (none is
    skipped)."""
    a, b = zenoh_pair
    listener = LatestCalibration()
    subscriber = a.declare_subscriber(keys.calibration("upcon"), listener)
    try:
        publisher = matched_publisher(b, keys.calibration("upcon"))
        doc = calibration_to_doc(calibrate(observe(make_rig(seed=2), seed=2).observations).calibration)
        for solve in (1, 2):
            publisher.put(json.dumps({**doc, "solve": solve}).encode())
        taken = []
        assert wait_for(lambda: taken.extend(listener.take()) or len(taken) >= 2), taken
        assert [m.solve for m in taken] == [1, 2] and listener.latest.solve == 2
        assert listener.take() == []
    finally:
        subscriber.undeclare()


def test_solve_numbers_skipped_are_said_to_be_solves_not_kept():
    run_dir = Path("runs/x")
    numbering = SolveNumbering()
    notes = [numbering.note(solve, run_dir) for solve in (2, 3, 6, 7)]
    log = run_dir / "logs" / "calibrator.log"
    assert notes == [f"  (solve 1 not kept: see {log})", "", f"  (solves 4-5 not kept: see {log})", ""]
    resumed = SolveNumbering()
    assert "resumed" in resumed.note(21, run_dir, resumed=True) and resumed.note(22, run_dir) == ""
    assert SolveNumbering().note(None, run_dir) == ""


def test_up_and_a_standalone_calibrator_print_the_web_viewers_address(tmp_path):
    """The address is printed, not left in logs/calibrator.log only."""
    web_port, grpc_port = free_port(), free_port()
    up = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "up", rig_file(tmp_path, 4), "--duration-s", "120", "--run-dir",
         str(tmp_path / "run"), "--listen", f"tcp/127.0.0.1:{free_port()}", "--rerun", f"serve={web_port},{grpc_port}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = wait_for_line(up, "Rerun web viewer: http://", timeout_s=120)
        assert f":{web_port}/?url=rerun%2Bhttp%3A%2F%2F" in line and f"%3A{grpc_port}%2Fproxy" in line
    finally:
        stop(up, grace_s=30)
    web_port, grpc_port = free_port(), free_port()
    calibrator = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "calibrator", "--rig", "upcon", "--no-state", "--listen",
         f"tcp/127.0.0.1:{free_port()}", "--rerun", f"serve={web_port},{grpc_port}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = wait_for_line(calibrator, "Rerun web viewer: http://", timeout_s=120)
        assert f":{web_port}/?url=" in line
    finally:
        stop(calibrator, grace_s=30)


def test_up_passes_the_rerun_frame_period_to_the_calibrator(tmp_path):
    """`camnet up --rerun-frame-period-s` reaches its calibrator, which would otherwise log frames at the 10 s
    default. The calibrator's own parser reads what up builds for it."""
    rig_path = rig_file(tmp_path, 4)
    rig = load_rig(rig_path)
    for flags, period_s in (([], FRAME_PERIOD_S), (["--rerun-frame-period-s", "0"], 0.0),
                            (["--rerun-frame-period-s", "2.5"], 2.5)):
        args = build_parser(only="up").parse_args(["up", rig_path, "--rerun", "save=x.rrd", *flags])
        session_id = new_session_id()
        spec = _network_spec(args, Path(rig_path), rig, tmp_path / "run", session_id)
        calibrator = build_parser(only="calibrator").parse_args(["calibrator", "--rig", rig_path, *spec.calibrator])
        assert calibrator.rerun_frame_period_s == period_s and calibrator.rerun == ["save=x.rrd"], spec.calibrator
        assert calibrator.session_id == session_id, spec.calibrator


def test_up_refuses_a_negative_rerun_frame_period_in_one_line_before_starting_nodes(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "camnet.cli", "up", "--rerun-frame-period-s", "-1", "--run-dir",
                           str(tmp_path / "run")], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "--rerun-frame-period-s" in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()
