"""Bounds on what the codecs, the rig file and the calibrator take: pixels, K, distortion, image sides,
tracks per solve, and documents of another rig."""

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, observations_to_doc, parse_calibration, parse_observations
from camnet.io.rig import load_rig
from camnet.io.rig_match import calibration_mismatch, observations_mismatch
from camnet.model.calibration import Calibration
from camnet.sim.simulate import make_rig, observe

ROOT = Path(__file__).resolve().parents[1]
SIM_RIG = ROOT / "config" / "sim.yaml"


@pytest.fixture(scope="module")
def obs_doc() -> dict:
    return observations_to_doc(observe(make_rig(seed=5), noise_px=0.3, seed=5).observations)


def refused(doc: dict, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        parse_observations(doc, **kwargs)
    return str(info.value)


def test_a_pixel_outside_its_image_is_named(obs_doc):
    doc = json.loads(json.dumps(obs_doc))
    width = doc["cameras"][2]["width"]
    cam_id = doc["cameras"][2]["id"]
    track = next(i for i, t in enumerate(doc["tracks"]) if cam_id in t["observations"])
    doc["tracks"][track]["observations"][cam_id] = [width + 500.0, 10.0]
    message = refused(doc)
    assert message.startswith(f"tracks[{track}].observations.{cam_id}: pixel ({width + 500:g}, 10)")
    assert "outside" in message
    # Within the margin (sub-pixel refinement at the border) is fine.
    doc["tracks"][track]["observations"][cam_id] = [width - 0.5 + 3.0, -2.0]
    parse_observations(doc)


@pytest.mark.parametrize(("K", "needle"), [
    ([[1000, 0, 640], [0, 1000, 512], [0, 0, 2]], "not a camera matrix"),
    ([[1000, 0, 640], [5, 1000, 512], [0, 0, 1]], "not a camera matrix"),
    ([[1000, 0, 640], [0, 1000, 512], [1e-3, 0, 1]], "not a camera matrix"),
    ([[-1000, 0, 640], [0, 1000, 512], [0, 0, 1]], "focal lengths must be positive"),
])
def test_k_must_be_a_camera_matrix(obs_doc, K, needle):
    doc = json.loads(json.dumps(obs_doc))
    doc["cameras"][0]["K"] = K
    assert refused(doc).startswith("cameras[0].K: " + needle)


@pytest.mark.parametrize(("dist", "model", "where"), [
    ([1e6, 0, 0, 0, 0], "pinhole", "dist[0]"),
    ([0, 0, 3.0, 0, 0], "pinhole", "dist[2]"),
    ([0.1, 0, 0, -500], "fisheye", "dist[3]"),
])
def test_distortion_beyond_any_lens_is_refused(obs_doc, dist, model, where):
    doc = json.loads(json.dumps(obs_doc))
    doc["cameras"][1].update(dist=dist, model=model)
    assert refused(doc).startswith(f"cameras[1].{where}: ")


def test_an_image_side_beyond_the_frame_header_is_refused(obs_doc, tmp_path):
    doc = json.loads(json.dumps(obs_doc))
    doc["cameras"][0]["width"] = 70000
    assert refused(doc).startswith("cameras[0].width: 70000 px is larger than any camera's image")
    rig = yaml.safe_load(SIM_RIG.read_text())
    rig["cameras"][2]["sim"]["width"] = 70000
    path = tmp_path / "wide.yaml"
    path.write_text(yaml.safe_dump(rig))
    with pytest.raises(InputError, match=r"cameras\[2\]\.sim\.width: 70000 px is larger"):
        load_rig(path)


def test_tracks_beyond_the_cap_are_refused_or_subsampled(obs_doc):
    n = len(obs_doc["tracks"])
    assert refused(obs_doc, max_tracks=n - 1).startswith(f"tracks: {n} tracks, more than the {n - 1}")
    first = parse_observations(obs_doc, max_tracks=10, subsample_seed=1)
    again = parse_observations(obs_doc, max_tracks=10, subsample_seed=1)
    assert len(first.track_ids) == 10 and np.array_equal(first.track_ids, again.track_ids)
    assert len(parse_observations(obs_doc, max_tracks=n).track_ids) == n


def test_observations_of_another_rig_are_told_apart(obs_doc):
    rig = load_rig(SIM_RIG)
    obs = parse_observations(obs_doc)
    assert observations_mismatch(rig, obs) is None
    wider = replace(obs, stereo=replace(obs.stereo, baseline_m=0.5))
    assert "stereo baseline 0.5 m, the rig's is 0.125 m" in observations_mismatch(rig, wider)
    smaller = replace(obs, cameras=(replace(obs.cameras[0], width=640),) + obs.cameras[1:])
    assert "is 640x1024, the rig file says 1280x1024" in observations_mismatch(rig, smaller)
    stranger = replace(obs, cameras=(replace(obs.cameras[3], id="cam9"),) + obs.cameras[:3])
    assert "camera 'cam9' is not in rig 'sim'" in observations_mismatch(rig, stranger)


def sim_calibration(baseline_scale: float = 1.0) -> Calibration:
    cameras = tuple(load_rig(SIM_RIG).simulated_truth())
    cameras = tuple(replace(c, t=c.t * baseline_scale) for c in cameras)
    return Calibration(cameras=cameras, point_ids=np.zeros(0, dtype=np.int64), points=np.zeros((0, 3)),
                       rms_reprojection_px=0.3, world_frame="left")


def test_a_calibration_of_another_rig_is_told_apart():
    rig = load_rig(SIM_RIG)
    assert calibration_mismatch(rig, parse_calibration(calibration_to_doc(sim_calibration()))) is None
    found = calibration_mismatch(rig, sim_calibration(4.0))
    assert "stereo cameras are 0.5 m apart, the rig's baseline is 0.125 m" in found


def run_camnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], capture_output=True, text=True, timeout=300)


def test_calibrate_refuses_too_many_tracks_in_one_line_or_subsamples(tmp_path, obs_doc):
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(obs_doc))
    n = len(obs_doc["tracks"])
    proc = run_camnet("calibrate", str(src), "-o", str(out), "--max-tracks", "40")
    assert proc.returncode != 0 and not out.exists()
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"tracks: {n} tracks, more than the 40" in lines[0] and "--subsample-tracks" in lines[0]
    proc = run_camnet("calibrate", str(src), "-o", str(out), "--max-tracks", "40", "--subsample-tracks", "--json")
    assert proc.returncode == 0, proc.stderr
    assert f"solving 40 of the {n} tracks" in proc.stderr
    assert json.loads(proc.stdout)["points"] <= 40


def test_status_flags_a_phantom_driver_and_statistics_without_a_token():
    from camnet.bus.stats import CameraSeen, NodeStats
    from camnet.commands.status import format_cameras, suspicious

    def stats(kind, node_id, fps, cameras=None):
        return NodeStats("r", kind, node_id, fps, 10, 0, 1, cameras=cameras or {})

    seen = {"left": CameraSeen(0.01, 30.0, False), "mono_a": CameraSeen(12.5, 0.0, True)}
    all_stats = {("matcher", "matcher"): stats("matcher", "matcher", 3.0, seen),
                 ("driver", "left"): stats("driver", "left", 30.2),
                 ("driver", "mono_a"): stats("driver", "mono_a", 999.0),
                 ("driver", "ghost"): stats("driver", "ghost", 999.0)}
    live = [("matcher", "matcher"), ("driver", "left"), ("driver", "mono_a")]
    found = suspicious(live, all_stats)
    assert found == ["driver ghost: statistics without a liveliness token (a node gone, or a peer publishing "
                     "in its name)",
                     "driver ghost: claims 999.0 fps, but the matcher knows no camera 'ghost'",
                     "driver mono_a: claims 999.0 fps, the matcher receives 0.0 fps"]
    lines = format_cameras(all_stats)
    assert any("mono_a" in line and "MISSING" in line and "12.5 s ago" in line for line in lines)
    assert not any("left" in line and "MISSING" in line for line in lines)
