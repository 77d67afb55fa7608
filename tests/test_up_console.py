"""What `camnet up` prints: every calibration, numbered as the calibrator publishes it, and where to
watch it in Rerun."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from camnet.bus import keys
from camnet.commands.up import LatestCalibration, SolveNumbering
from camnet.geometry.calibrate import calibrate
from camnet.io.formats import calibration_to_doc
from camnet.sim.simulate import make_rig, observe
from tests.conftest import free_port, matched_publisher, wait_for
from tests.test_network import rig_file
from tests.test_web_viewer import stop, wait_for_line

ROOT = Path(__file__).resolve().parent.parent


def test_two_calibrations_in_quick_succession_are_both_shown(zenoh_pair):
    """Measured before: only the latest was kept, so a console that looked after the second arrived
    never showed the first ('one console run skipped solve 1')."""
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
        assert [d["solve"] for d in taken] == [1, 2] and listener.latest["doc"]["solve"] == 2
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
    """Measured before: `camnet up --rerun serve` left the address in logs/calibrator.log only."""
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
