"""KITTI raw through the live nodes: v4l2 drivers replaying the recorded frames, matcher and calibrator as processes.

config/kitti.yaml replays the four cameras with their recorded capture times
(cam 3 is stamped 6.6-6.8 ms before cam 0; every frame set holds the grey
pair plus one colour camera) and KITTI's published intrinsics; the
calibrator holds the stereo pair's published pose, which the rig file
gives. That is the offline `all-K` scenario (benchmarks/bench_kitti.py),
so the live result must agree with the offline one on the same frames, and
both with the published calibration within what this rig permits (see
tests/test_kitti_calibration.py and the data set's README).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from camnet.datasets.kitti import KittiExtract, pooled_observations, prepare_scenario
from camnet.datasets.published import compare
from camnet.io.rig import load_rig
from camnet.solve import Options, calibrate
from camnet.testing.live_rig import calibrate_live
from tests._groundtruth import KITTI_ROOT, require
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parents[1]
RIG = ROOT / "config" / "kitti.yaml"


@pytest.fixture(scope="module")
def kitti():
    return KittiExtract.open(require(KITTI_ROOT))


@pytest.fixture(scope="module")
def offline(kitti):
    """The offline all-K result on the same four frame sets, with the live matcher's pool size."""
    obs = pooled_observations(kitti)
    prepared, head = prepare_scenario(obs, kitti.cameras, "all-K")
    cal = calibrate(prepared, Options(), initial=head).calibration
    return compare(cal, obs, kitti.cameras)


def test_live_network_calibrates_every_camera_like_the_offline_pipeline(kitti, offline, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the rig file's paths are relative to the rig file, wherever camnet runs
    # The timeout only bounds the test (how fast: docs/benchmarks.md, "Real images: KITTI"; not tests).
    cal, obs, _ = calibrate_live(RIG, run_dir=tmp_path / "run",
                                 endpoint=f"tcp/127.0.0.1:{free_port()}", timeout_s=300.0)
    live = compare(cal, obs, kitti.cameras)
    # Every camera, from frame sets of the pair plus one colour camera; a few hundred tracks tie each
    # colour camera to the pair, as offline (fewer where a loaded matcher drops more frame sets while busy).
    assert {c.id for c in cal.cameras} == {"0", "1", "2", "3"}
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), dtype=bool)
    seen[obs.track_index, obs.cam_index] = True
    with_pair = seen[:, obs.index_of("0")] & seen[:, obs.index_of("1")]
    for colour in ("2", "3"):
        assert np.sum(with_pair & seen[:, obs.index_of(colour)]) >= 200
    # The published intrinsics reached the solver through the rig file and the matcher.
    for cam in obs.cameras:
        assert cam.fixed == frozenset({"K", "dist"}) and np.allclose(cam.K, kitti.cameras[cam.id].K)

    # Against the published calibration, with the offline tolerances (tests/test_kitti_calibration.py): the
    # pair is fully known, 0.2 deg is 3 px, and the colour cameras fire ~7 ms early on a car doing ~5 m/s (3-5 cm).
    assert live.rms_reprojection_px < 0.6
    assert abs(live.distance_rel) < 0.005
    for cam_id in ("2", "3"):
        cam = live.camera(cam_id)
        assert cam.rotation_deg < 0.2 and cam.centre_mm < 30.0, cam

    # Against the offline pipeline: the same engine on the same frames. The pools differ a little (the
    # matcher sees the frame sets in its own order, drops some while busy and meets them again on the
    # next pass, so its 3000 kept tracks are not the offline ones), hence not equal, but close: hundredths of
    # a percent of scale apart, centres millimetres, rotations hundredths of a degree.
    assert abs(live.distance_rel - offline.distance_rel) < 0.003
    for cam_id in ("1", "2", "3"):
        a, b = live.camera(cam_id), offline.camera(cam_id)
        assert abs(a.centre_mm - b.centre_mm) < 10.0 and abs(a.rotation_deg - b.rotation_deg) < 0.05, (a, b)


# ---------------------------------------------------------------- no data needed


def test_the_kitti_rig_file_holds_what_the_live_run_needs():
    rig = load_rig(RIG)
    assert [c.id for c in rig.cameras] == ["0", "1", "2", "3"]
    assert (rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m) == ("0", "1", 0.5372)
    # Cam 3 is stamped up to 8.8 ms before cam 0; frames are ~103 ms apart.
    assert 8.8 < rig.sync.tolerance_ms < 50
    stamps = {c.id: c.config.timestamps for c in rig.cameras}
    assert stamps["2"] == stamps["0"]  # no image_02/timestamps.txt: cam 2 fired at cam 0's trigger
    assert stamps["3"].endswith("image_03/timestamps.txt")
    # Cameras that loop together share one pass.
    assert {(c.config.frame_range, c.config.speed, c.config.loop) for c in rig.cameras} == {((1, 16), 0.15, True)}
    assert all(c.intrinsics.fixed == frozenset({"K", "dist"}) for c in rig.cameras)


def test_the_rig_files_sync_settings_and_intrinsics_reach_the_matcher():
    from camnet.commands.matcher import node_config_from_args
    from camnet.io.rig import camera_info

    rig = load_rig(RIG)
    config = node_config_from_args(argparse.Namespace(), rig)
    assert (config.sync_tolerance_ms, config.max_wait_s) == (10.0, 2.0)
    config = node_config_from_args(argparse.Namespace(sync_tolerance_ms=3.0), rig)  # a flag overrides the file
    assert (config.sync_tolerance_ms, config.max_wait_s) == (3.0, 2.0)
    info = camera_info(rig, "3", 1392, 512)
    assert (info.width, info.height, info.K[0, 0], info.dist[0]) == (1392, 512, 903.7596, -0.3639558)
    assert info.fixed == frozenset({"K", "dist"})
