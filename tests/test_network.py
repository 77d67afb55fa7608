"""The whole simulated network, headless: `camnet up` with drivers, matcher and calibrator.

Simulated time runs on the wall clock, so the rigs are small images at a low
frame rate, and each run ends on progress, not after a fixed time: at the
first calibration from `FRAME_SETS` pooled frame sets (`--until-frame-sets`),
however long a loaded machine takes to pool them, within `LIMIT_S`.
"""

import json
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from camnet.bus import keys
from camnet.io.formats import parse_calibration
from camnet.io.rig import load_rig
from camnet.model.accuracy import compare_cameras
from tests.conftest import free_port, stop_process
from tests.test_viz import read_rrd

BOX_CENTRE = [0.0625, 0.0, 0.65]
# A calibration from one frame set can be a few tenths of a percent off the scale; from ten or more pooled it is
# well within what the tests ask (0.5% of the scale, 1% of the focal lengths): twenty leave a margin
# (docs/benchmarks.md, "The test suite and `scripts/up`").
FRAME_SETS = 20
LIMIT_S = 300  # --duration-s: the outer limit, past which `camnet up` fails (several times a loaded run's)
UNTIL = ["--until-frame-sets", str(FRAME_SETS), "--duration-s", str(LIMIT_S)]
# What `camnet up` may take beyond LIMIT_S: starting its nodes and writing its results.
END_TIMEOUT_S = LIMIT_S + 300


def sim_camera(f_px: float, centre, *, look_at=None, fps: float = 4.0) -> dict:
    cam = {"width": 640, "height": 512, "encoding": "mono8", "fps": fps, "f_px": f_px,
           "cx_px": 319.5, "cy_px": 255.5, "centre_m": list(centre)}
    if look_at is not None:
        cam["look_at_m"] = list(look_at)
    return cam


def rig_file(tmp_path, n_cameras: int) -> str:
    """The paper's rig at half resolution, with more cameras on an arc beyond four."""
    cameras = [
        {"id": "left", "driver": "sim", "sim": sim_camera(750, [0.0, 0.0, 0.0])},
        {"id": "right", "driver": "sim", "sim": sim_camera(750, [0.125, 0.0, 0.0])},
        {"id": "mono_a", "driver": "sim", "sim": sim_camera(650, [-0.30, 0.0, 0.05], look_at=BOX_CENTRE)},
        {"id": "mono_b", "driver": "sim", "sim": sim_camera(700, [0.425, 0.0, 0.05], look_at=BOX_CENTRE)},
    ]
    for i in range(n_cameras - 4):
        angle = np.deg2rad(-60 + 120 * (i + 0.5) / (n_cameras - 4))
        centre = np.array(BOX_CENTRE) + 0.6 * np.array([np.sin(angle), 0.0, -np.cos(angle)])
        centre[1] += 0.1 if i % 2 else -0.1
        cameras.append({"id": f"mono_{i + 2:02d}", "driver": "sim",
                        "sim": sim_camera(600 + 40 * i, centre.round(4).tolist(), look_at=BOX_CENTRE)})
    doc = {
        "rig": f"net{n_cameras}",
        "stereo": {"left": "left", "right": "right", "baseline_m": 0.125, "parallel": True},
        "scene": {"seed": 7, "box_centre_m": BOX_CENTRE, "box_size_m": [0.10, 0.17, 0.08],
                  "box_rotation_deg_per_s": 20.0, "wall_z_m": 1.2, "wall_x_range_m": [-1.5, 1.6],
                  "wall_y_range_m": [-0.8, 0.25], "floor_y_m": 0.25, "floor_z_range_m": [0.2, 1.2]},
        "cameras": cameras,
    }
    path = tmp_path / f"rig{n_cameras}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return str(path)


def publish_junk_calibrations(endpoint: str, rig_name: str, stop: threading.Event) -> None:
    """`{}`, 100k-deep JSON and bytes that are not UTF-8 on the calibration key, every 2 s for 30 s or
    until `stop` is set.

    Junk there must stop no node. Sent for 30 s, not the whole run: parsing it every 0.5 s all along slows
    every node, and the run takes twice as long (docs/benchmarks.md, "The test suite and `scripts/up`").
    """
    from camnet.bus.session import BusOptions, open_session

    with open_session(BusOptions(connect=(endpoint,))) as peer:
        publisher = peer.declare_publisher(keys.calibration(rig_name))
        for _ in range(15):
            for junk in (b"{}", b"[" * 100_000, b"\xff\xfe"):
                publisher.put(junk)
            if stop.wait(2.0):
                return


def run_up(tmp_path, args: list[str], *, timeout_s: float) -> str:
    """`camnet up ARGS` with its run directory in tmp_path/run, on a loopback port of its own; its stdout,
    after asserting it ended well (else its output and the nodes' log tails)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "up", *args, "--run-dir", str(tmp_path / "run"), "--listen",
         f"tcp/127.0.0.1:{free_port()}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    finally:
        stop_process(proc)  # on a timeout: camnet up stops its nodes, which a SIGKILL to it alone would leave running
    logs = "\n".join(p.read_text()[-1500:] for p in (tmp_path / "run").rglob("*.log"))
    assert proc.returncode == 0, stdout + stderr + logs
    return stdout


@pytest.mark.parametrize("n_cameras", [4, 8])
def test_simulated_network_calibrates_to_scale(tmp_path, n_cameras):
    rig_path = rig_file(tmp_path, n_cameras)
    out = tmp_path / "calibration.json"
    rrd = tmp_path / "run.rrd"
    session = tmp_path / "session.mcap"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camnet.cli", "up", rig_path, *UNTIL, "--run-dir",
         str(tmp_path / "run"), "-o", str(out), "--listen", endpoint, "--rerun", f"save={rrd}",
         "--record", str(session)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # Any peer may publish on the calibration key: junk there, all the while camnet up runs, stops nothing.
    # Published from a thread, so that camnet up's output is read meanwhile (a full pipe would stall it).
    stop_junk = threading.Event()
    junk = threading.Thread(target=publish_junk_calibrations, args=(endpoint, load_rig(rig_path).name, stop_junk),
                            daemon=True)
    try:
        if n_cameras == 4:
            junk.start()
        stdout, stderr = proc.communicate(timeout=END_TIMEOUT_S)
    finally:
        stop_junk.set()
        if junk.is_alive():
            junk.join(timeout=60)
        stop_process(proc)
    logs = "\n".join(p.read_text()[-1500:] for p in (tmp_path / "run").rglob("*.log"))
    assert proc.returncode == 0, stdout + stderr + logs
    if n_cameras == 4:  # the junk arrived, and was refused
        assert "ignoring a message that is no calibration" in stderr, stderr
    cal = parse_calibration(json.loads(out.read_text()))
    assert json.loads(out.read_text())["frame_sets"] >= FRAME_SETS
    truth = load_rig(rig_path).simulated_truth()
    comparison = compare_cameras(cal, truth)
    assert len(cal.cameras) == n_cameras
    assert abs(comparison.scale_rel) < 0.005, stdout
    assert max(abs(e.focal_rel) for e in comparison.cameras) < 0.01, stdout
    assert "vs truth" in stdout and "final calibration" in stdout
    # Every calibration is a line, numbered as the calibrator publishes it; a number skipped is said.
    lines = [line for line in stdout.splitlines() if re.match(r"\s*[\d.]+ s  solve ", line)]
    numbers = [int(line.split(" solve ")[1].split()[0]) for line in lines]
    assert numbers == sorted(set(numbers)) and numbers, stdout
    for before, (number, line) in zip([0, *numbers], zip(numbers, lines, strict=True), strict=False):
        assert (number == before + 1) != ("not kept" in line), line

    # The run's Rerun recording: every camera, the cloud, the series, one entry per solve.
    data = read_rrd(rrd)
    series = data["/series/network/rms_px"]["solve"]
    solves = len(series)
    assert solves >= 1 and series == sorted(set(series))
    assert data[f"/world/cameras/{cal.world_frame}"]["solve"] == series  # the left camera is in every one
    for cam in cal.cameras:
        # Every solve that placed it, from the first on to the last: a first pool may not place every camera yet.
        placed = data[f"/world/cameras/{cam.id}"]["solve"]
        assert placed and placed == series[solves - len(placed):], (cam.id, placed, series)
        assert len(data[f"/world/cameras/{cam.id}"]["Pinhole:image_from_camera"]) == len(placed)
        assert len(data[f"/world/cameras/{cam.id}/image"]["EncodedImage:blob"]) >= 1
        assert len(data[f"/series/focal_error_pct/{cam.id}"]["Scalars:scalars"]) == len(placed)
    assert len(data["/world/points"]["Points3D:positions"]) == solves
    assert len(data["/series/network/scale_error_pct"]["Scalars:scalars"]) == solves

    # The session recorded beside it: every camera's frames and the calibrations.
    with open(session, "rb") as f:
        topics = {channel.topic for channel in make_reader(f).get_summary().channels.values()}
    rig_name = load_rig(rig_path).name
    assert {keys.frame(rig_name, cam.id) for cam in cal.cameras} <= topics
    assert keys.calibration(rig_name) in topics and keys.observations(rig_name) in topics


@pytest.mark.parametrize(("flags", "fragment"), [
    (["--duration-s", "0"], "--duration-s"),
    (["--until-frame-sets", "0"], "--until-frame-sets"),
    (["--rerun", "bogus"], "--rerun"),
    (["missing-rig.yaml"], "missing-rig.yaml"),
])
def test_up_refuses_bad_input_in_one_line_before_starting_nodes(tmp_path, flags, fragment):
    proc = subprocess.run([sys.executable, "-m", "camnet.cli", "up", *flags, "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and fragment in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()


def test_up_that_does_not_reach_its_frame_sets_in_time_fails_in_one_line(tmp_path):
    """--until-frame-sets asks for a calibration from that many frame sets; --duration-s bounds the wait, and
    a run that ends before is an error, not the last calibration passed off as the one asked for."""
    proc = subprocess.Popen([sys.executable, "-m", "camnet.cli", "up", rig_file(tmp_path, 4), "--until-frame-sets",
                             "1000000", "--duration-s", "3", "--run-dir", str(tmp_path / "run"), "--listen",
                             f"tcp/127.0.0.1:{free_port()}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = proc.communicate(timeout=END_TIMEOUT_S)
    finally:
        stop_process(proc)
    lines = stderr.strip().splitlines()
    assert proc.returncode == 2 and lines, stdout + stderr
    expected = "camnet up: error: --until-frame-sets: no calibration from 1000000 frame sets in 3 s"
    assert lines[-1].startswith(expected), stderr
    assert "final calibration" not in stdout, stdout


def test_up_with_feature_stages_beside_the_drivers_calibrates(tmp_path):
    """`camnet up --features`: each driver detects its own camera's features; the matcher only matches them."""
    rig_path = rig_file(tmp_path, 4)
    out = tmp_path / "calibration.json"
    stdout = run_up(tmp_path, [rig_path, "--features", *UNTIL, "-o", str(out)], timeout_s=END_TIMEOUT_S)
    logs = {p.stem: p.read_text() for p in (tmp_path / "run" / "logs").glob("*.log")}
    # Every camera's features came from its own stage, none was detected by the matcher.
    for camera_id in ("left", "right", "mono_a", "mono_b"):
        assert f"camera '{camera_id}': features from its own stage" in logs["matcher"], logs["matcher"][-3000:]
    cal = parse_calibration(json.loads(out.read_text()))
    comparison = compare_cameras(cal, load_rig(rig_path).simulated_truth())
    assert len(cal.cameras) == 4
    assert abs(comparison.scale_rel) < 0.005, stdout
    assert max(abs(e.focal_rel) for e in comparison.cameras) < 0.01, stdout


def test_up_publishes_the_cameras_it_can_place_and_names_the_one_looking_away(tmp_path):
    """A fifth camera that sees nothing the others see: the four are calibrated and published, the fifth
    is named with its reason on every console line and in the final table, not every solve refused for it
    and `camnet up` ended with no calibration."""
    doc = yaml.safe_load(Path(rig_file(tmp_path, 4)).read_text())
    doc["rig"] = "away5"
    doc["cameras"].append({"id": "away", "driver": "sim",
                           "sim": sim_camera(700, [0.0, 0.0, 0.0], look_at=[0.0, 0.0, -1.0])})
    rig_path = tmp_path / "away5.yaml"
    rig_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "calibration.json"
    stdout = run_up(tmp_path, [str(rig_path), *UNTIL, "-o", str(out)], timeout_s=END_TIMEOUT_S)
    published = json.loads(out.read_text())
    cal = parse_calibration(published)
    assert {c.id for c in cal.cameras} == {"left", "right", "mono_a", "mono_b"}
    assert set(published["diagnostics"]["cameras_left_out"]) == {"away"}
    comparison = compare_cameras(cal, load_rig(rig_path).simulated_truth())
    assert abs(comparison.scale_rel) < 0.01, stdout
    lines = [line for line in stdout.splitlines() if re.match(r"\s*[\d.]+ s  solve ", line)]
    assert lines and all("missing: away (" in line for line in lines), stdout
    assert re.search(r"^away\s+not calibrated: \S", stdout, flags=re.MULTILINE), stdout
