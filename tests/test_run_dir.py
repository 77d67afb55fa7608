"""What `camnet up` leaves in its run directory, and the lines that name it."""

import argparse
import json
import re
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camnet.commands.up import RunFollower, _finish
from camnet.commands.up_console import final_report, progress_line, summarise
from camnet.io.formats import parse_calibration, write_json_atomic
from camnet.io.messages import CalibrationMessage, ObservationsMessage, observations_message_to_doc
from camnet.io.run_dir import default_run_dir, observations_behind
from camnet.live.moved_cameras import drop_before
from camnet.live.policy import LIVE_FREE
from camnet.sim.simulate import make_rig, observe
from camnet.solve.options import Options
from camnet.solve.pipeline import calibrate
from camnet.solve.report.verdict import Level


@pytest.fixture(scope="module")
def live_like():
    """A calibration message as the calibrator publishes it, and the observations message behind it."""
    rig = make_rig(n_points=300, seed=4)
    obs = observe(rig, noise_px=0.3, seed=4).observations
    obs_message = ObservationsMessage(obs, frame_sets=7, latest_capture_ns=123456789)
    cal_message = CalibrationMessage(calibrate(obs, Options(free=LIVE_FREE)).calibration, frame_sets=7,
                                     latest_capture_ns=123456789, solve=3, status=Level.GOOD)
    return rig, cal_message, obs_message


def test_the_default_run_directory_names_the_rig_and_the_time():
    path = default_run_dir("sim", now_s=0.0)
    assert path.parts[0] == "runs" and re.fullmatch(r"sim-\d{8}-\d{6}", path.name)


def test_the_observations_behind_a_calibration_are_those_of_its_solve_only(tmp_path, live_like):
    _, cal_message, obs_message = live_like
    path = tmp_path / "observations.json"
    assert observations_behind(path, cal_message) is None  # none written
    write_json_atomic(path, observations_message_to_doc(replace(obs_message, frame_sets=2, latest_capture_ns=2)))
    assert observations_behind(path, replace(cal_message, frame_sets=2, latest_capture_ns=2)).frame_sets == 2
    assert observations_behind(path, replace(cal_message, frame_sets=2, latest_capture_ns=1)) is None
    assert observations_behind(path, cal_message) is None  # a later solve's
    path.write_text("{")
    assert observations_behind(path, replace(cal_message, frame_sets=2, latest_capture_ns=2)) is None


def test_the_run_directory_holds_the_results_and_the_last_lines_name_them(tmp_path, live_like):
    rig, cal_message, obs_message = live_like
    follower = RunFollower(argparse.Namespace(), truth=None)
    run_dir = tmp_path / "runs" / "sim-1"
    run_dir.mkdir(parents=True)
    write_json_atomic(run_dir / "observations.json", observations_message_to_doc(obs_message))  # the calibrator's
    text = _finish(argparse.Namespace(output=None), run_dir, cal_message, follower, truth=None, restarts={})
    names = sorted(p.name for p in run_dir.iterdir())
    assert names == ["calibration.json", "calibration.yaml", "colmap", "observations.json", "points.ply",
                     "report.html"]
    assert json.loads((run_dir / "observations.json").read_text())["frame_sets"] == 7
    assert parse_calibration(json.loads((run_dir / "calibration.json").read_text())).report is not None
    fs = cv2.FileStorage(str(run_dir / "calibration.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    fs.release()
    assert (run_dir / "colmap" / "points3D.txt").stat().st_size > 0
    html = (run_dir / "report.html").read_text()
    assert "Needs the observations" not in html  # the residual plots have them
    for name in names:
        assert name in text
    assert f"open {run_dir / 'report.html'}" in text and "camnet export" in text and "camnet calibrate" in text


def test_a_simulated_run_keeps_its_truth_and_its_report_shows_what_the_console_does(tmp_path, live_like):
    import subprocess
    import sys

    from camnet.model.accuracy import compare_cameras

    rig, cal_message, obs_message = live_like
    truth = list(rig.cameras)  # the simulation's cameras, in the left camera's frame as Rig.simulated_truth gives
    follower = RunFollower(argparse.Namespace(), truth=truth)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_json_atomic(run_dir / "observations.json", observations_message_to_doc(obs_message))
    text = _finish(argparse.Namespace(output=None), run_dir, cal_message, follower, truth=truth, restarts={})
    assert "truth.json" in text and "against the simulation's ground truth:" in text
    kept = parse_calibration(json.loads((run_dir / "truth.json").read_text())).cameras
    for cam, true in zip(kept, truth, strict=True):
        assert cam.id == true.id and np.allclose(cam.K, true.K) and np.allclose(cam.R, true.R)
        assert np.allclose(cam.t, true.t)
    c = compare_cameras(cal_message.calibration, truth)
    again = tmp_path / "again.html"
    proc = subprocess.run([sys.executable, "-m", "camnet", "report", str(run_dir / "calibration.json"), "--truth",
                           str(run_dir / "truth.json"), "-o", str(again)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for html in ((run_dir / "report.html").read_text(), again.read_text()):
        for e in c.cameras:  # the console's numbers (format_comparison), per camera
            line = next(line for line in text.splitlines() if line.startswith(f"{e.id} ") and "%" not in line
                        and len(line.split()) == 6)
            focal, _, centre, _, rotation = line.split()[1:]
            assert (f'<td>{e.id}</td><td class="num">{focal}</td>' in html
                    and f'<td class="num">{float(rotation):.4f}</td>' in html), (line, e)
        assert f"the scale is off by {100 * c.scale_rel:+.3f}%" in html


def test_the_final_lines_are_readable_units_with_sigmas_and_the_verdict(live_like):
    _, cal_message, _ = live_like
    text = final_report(cal_message.calibration, truth=None)
    assert "[" not in text, "raw arrays"
    mono_a = next(line for line in text.splitlines() if line.startswith("mono_a"))
    assert re.search(r"\d+\.\d ± \d+\.\d", mono_a) and mono_a.split()[-1] in ("good", "usable", "poor")
    assert "verdict: " in text


def test_up_replays_a_recording_into_a_run_directory(tmp_path):
    """`camnet up RIG --replay SESSION`: no drivers, the recording's frames, results where it says."""
    import sys

    from tests.conftest import free_port, run_to_end
    from tests.test_network import rig_file
    from tests.test_replay_lockstep import write_session

    rig_path = rig_file(tmp_path, 4)
    session = tmp_path / "session.mcap"
    write_session(session, rig_path)
    out = tmp_path / "results"
    proc = run_to_end(
        [sys.executable, "-m", "camnet", "up", rig_path, "--replay", str(session), "--out", str(out),
         "--duration-s", "240", "--listen", f"tcp/127.0.0.1:{free_port()}"], timeout_s=400)
    logs = "\n".join(p.read_text()[-1500:] for p in out.rglob("*.log"))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    assert "replay: the session has been played to its end" in proc.stdout
    assert not list((out / "logs").glob("driver-*.log")), "a replay starts no driver"
    assert (out / "calibration.json").exists() and (out / "report.html").exists()
    assert f"files in {out}:" in proc.stdout


def test_a_partial_calibrations_run_directory_and_final_table_name_the_camera_left_out(tmp_path):
    # A live calibration without a camera that shares nothing yet: its observations still list it, and the
    # report and the COLMAP export take them so, not refusing them ("camera 'mono_04' is not in the calibration").
    obs = observe(make_rig(n_cameras=5, n_points=300, seed=4), noise_px=0.3, seed=4).observations
    away = obs.camera_ids[4]
    obs = drop_before(obs, {away: int(obs.track_ids.max()) + 1})
    cal = calibrate(obs, Options(free=LIVE_FREE)).calibration
    assert away not in {c.id for c in cal.cameras}
    cal_message = CalibrationMessage(cal, frame_sets=7, latest_capture_ns=1, solve=3)
    follower = RunFollower(argparse.Namespace(), truth=None)
    (tmp_path / "run").mkdir()
    write_json_atomic(tmp_path / "run" / "observations.json",
                      observations_message_to_doc(ObservationsMessage(obs, frame_sets=7, latest_capture_ns=1)))
    text = _finish(argparse.Namespace(output=None), tmp_path / "run", cal_message, follower, truth=None, restarts={})
    assert re.search(rf"^{away}\s+not calibrated: it has no observations", text, flags=re.MULTILINE), text
    assert "Needs the observations" not in (tmp_path / "run" / "report.html").read_text()
    images = (tmp_path / "run" / "colmap" / "images.txt").read_text()
    assert away not in images and "mono_a" in images
    line = progress_line(summarise(1.0, cal_message, truth=None))
    assert f"missing: {away} (it has no observations" in line, line
