"""A rig of the operator's own cameras under `camnet up`: every failing camera named at once, no OpenCV noise.

Cameras that cannot start are named all together, whether camnet sees it
before starting anything (an absent device, file or image) or a driver finds
it out (a file OpenCV cannot read); OpenCV's own log lines
(``[ WARN:0@0.062] global cap.cpp:212 ...``) never reach camnet's output or
the nodes' logs.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.conftest import free_port

OPENCV_LOG_MARKS = ("[ WARN:", "[ERROR:", "global cap", "moov atom")  # OpenCV's and its FFmpeg's


def v4l2_rig(directory: Path, sources: dict[str, str]) -> Path:
    ids = list(sources)
    doc = {"rig": "own", "stereo": {"left": ids[0], "right": ids[1], "baseline_m": 0.12},
           "cameras": [{"id": cid, "driver": "v4l2", "v4l2": {"source": src, "fps": 5, "loop": True}}
                       for cid, src in sources.items()]}
    path = directory / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def own_bus() -> tuple[str, str]:
    """`camnet up`'s nodes meet on a loopback port of their own, not on the default rendezvous."""
    return "--listen", f"tcp/127.0.0.1:{free_port()}"


def camnet(*args: str, cwd: Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    """Run camnet to its end; past `timeout_s` it is stopped as Ctrl-C would (so that `camnet up` stops its
    nodes), then killed, and the test fails."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_LOG_LEVEL", "OPENCV_FFMPEG_LOGLEVEL")}
    proc = subprocess.Popen([sys.executable, "-m", "camnet", *args], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        try:
            stdout, stderr = proc.communicate(timeout=30)
        finally:
            proc.kill()
            proc.wait()
        raise AssertionError(f"camnet {' '.join(args)} ran past {timeout_s} s:\n{stdout}\n{stderr}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def test_up_names_every_absent_camera_before_starting_anything(tmp_path):
    rig = v4l2_rig(tmp_path, {"usb": "/dev/video63", "clip": "clips/missing.mp4", "stills": "img/*.png"})
    proc = camnet("up", str(rig), "--duration-s", "5", "--run-dir", str(tmp_path / "run"), cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert lines[0] == f"camnet up: error: {rig}: 3 of 3 cameras cannot start:", proc.stderr
    assert "camera 'usb': no device /dev/video63" in lines[1]
    assert f"camera 'clip': no file '{tmp_path / 'clips' / 'missing.mp4'}'" in lines[2]
    assert (f"camera 'stills': no folder {tmp_path / 'img'} for its images (paths are relative to the rig file); "
            "put the camera's images there, or set its v4l2 source to where they are") in lines[3]
    assert len(lines) == 4 and proc.stdout == "" and not (tmp_path / "run").exists()


@pytest.mark.parametrize("restart", [(), ("--no-restart",)], ids=["restart", "no-restart"])
def test_up_names_every_camera_its_drivers_could_not_open_and_keeps_opencv_quiet(tmp_path, restart):
    for name in ("a.mp4", "b.mp4"):
        (tmp_path / name).write_bytes(b"not a video at all" * 100)
    (tmp_path / "frames").mkdir()
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "frames" / "0.png"), np.zeros((48, 64), np.uint8))
    rig = v4l2_rig(tmp_path, {"a": "a.mp4", "b": "b.mp4", "good": "frames/*.png"})
    elsewhere = tmp_path / "elsewhere"  # the rig's paths are relative to the rig file
    elsewhere.mkdir()
    # Restarting or not, the run ends: a driver that exits before it is up failed to start (its camera fails
    # again), and its sibling failing too is named with it.
    proc = camnet("up", str(rig), "--duration-s", "60", "--run-dir", str(tmp_path / "run"), *restart,
                  *own_bus(), cwd=elsewhere)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    error = proc.stderr[proc.stderr.index("camnet up: error:"):]
    assert error.startswith("camnet up: error: 2 of "), proc.stderr
    assert f"driver-a exited with status 2: camera 'a': cannot open '{tmp_path / 'a.mp4'}'" in error
    assert f"driver-b exited with status 2: camera 'b': cannot open '{tmp_path / 'b.mp4'}'" in error
    assert "driver-good" not in error and "restarting" not in proc.stdout, proc.stdout
    logs = "".join(p.read_text() for p in (tmp_path / "run" / "logs").glob("*.log"))
    for mark in OPENCV_LOG_MARKS:
        assert mark not in proc.stdout + proc.stderr + logs, (mark, proc.stderr, logs)


EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "v4l2-example.yaml"


def test_the_v4l2_example_runs_as_given_from_anywhere(tmp_path):
    """config/v4l2-example.yaml with no camera and nothing beside the repository: the image sequences it ships,
    found relative to the rig file, calibrated to the simulated rig they were rendered from."""
    from camnet.io.formats import load_json, parse_calibration
    from camnet.io.rig import load_rig

    run_dir = tmp_path / "run"
    # The first calibration comes well within the run on a busy machine (docs/benchmarks.md, "The live network").
    proc = camnet("up", str(EXAMPLE), "--until-frame-sets", "2", "--duration-s", "120", "--run-dir", str(run_dir),
                  *own_bus(), cwd=tmp_path, timeout_s=300.0)
    logs = "\n".join(p.read_text()[-1500:] for p in (run_dir / "logs").glob("*.log"))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    assert "final calibration:\n4 cameras" in proc.stdout
    for mark in OPENCV_LOG_MARKS:
        assert mark not in proc.stdout + proc.stderr + logs
    cal = parse_calibration(load_json(run_dir / "calibration.json"))
    truth = load_rig(EXAMPLE.parent / "example-images" / "sim-rig.yaml").simulated_truth()
    for cam, true in zip(cal.cameras, truth, strict=True):
        assert cam.id == true.id
        assert abs(cam.K[0, 0] / true.K[0, 0] - 1) < 0.05, (cam.id, cam.K[0, 0], true.K[0, 0])
        assert np.linalg.norm(cam.centre - true.centre) < 0.02, (cam.id, cam.centre, true.centre)


def test_the_v4l2_example_without_its_images_names_the_folder_to_put_them_in(tmp_path):
    rig = tmp_path / "v4l2-example.yaml"
    rig.write_text(EXAMPLE.read_text())  # the rig file alone, as copied out of the repository
    proc = camnet("up", str(rig), "--run-dir", str(tmp_path / "run"), cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and lines[0] == f"camnet up: error: {rig}: 4 of 4 cameras cannot start:", proc.stderr
    for line, camera_id in zip(lines[1:], ("left", "right", "mono_a", "mono_b"), strict=True):
        assert line == (f"  camera {camera_id!r}: no folder {tmp_path / 'example-images' / camera_id} for its images "
                        "(paths are relative to the rig file); put the camera's images there, or set its v4l2 source "
                        "to where they are")
    assert not (tmp_path / "run").exists()


def test_up_names_a_misspelt_key_in_one_line(tmp_path):
    rig = v4l2_rig(tmp_path, {"a": "/dev/video0", "b": "/dev/video1"})
    doc = yaml.safe_load(rig.read_text())
    doc["stereo"]["baseline"] = doc["stereo"].pop("baseline_m")
    rig.write_text(yaml.safe_dump(doc))
    proc = camnet("up", str(rig), "--run-dir", str(tmp_path / "run"), cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == f"camnet up: error: {rig}: unknown key 'baseline' in stereo (did you mean 'baseline_m'?)\n"
    assert not (tmp_path / "run").exists()
