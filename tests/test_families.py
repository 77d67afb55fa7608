"""The simulated real-rig families: what they are said to be."""

import numpy as np
import pytest

from camnet.model.accuracy import compare
from camnet.sim.families import (
    FAMILIES,
    HARD_FAMILIES,
    HEAD_BASELINE_M,
    NARROW_RING_RADIUS_M,
    RING_RADIUS_M,
    TAPE_SIGMA_M,
    family,
    observe_family,
)
from camnet.sim.simulate import observe
from camnet.solve import calibrate


def seen(observations, camera_id: str) -> set[int]:
    m = observations.index_of(camera_id)
    return set(observations.track_ids[observations.track_index[observations.cam_index == m]].tolist())


@pytest.mark.parametrize("name", FAMILIES + HARD_FAMILIES)
def test_the_pair_comes_first_in_the_left_frame_at_its_distance(name):
    rig = family(name, seed=4).rig
    left, right = rig.cameras[:2]
    np.testing.assert_allclose(left.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(left.t, 0.0, atol=1e-12)
    # A taped distance is a reading within a few of its sigmas; a head's baseline is exact.
    assert np.linalg.norm(right.centre) == pytest.approx(rig.baseline_m, rel=1e-12, abs=4 * rig.stereo_sigma_m)
    for cam in rig.cameras:  # every camera sees the scene in front of it
        assert np.median((rig.points @ cam.R.T + cam.t)[:, 2]) > 0


def test_a_ring_camera_opposite_the_head_sees_none_of_its_points():
    drawn = family("ring", seed=1)
    obs = observe(drawn.rig, noise_px=0.0, seed=1, normals=drawn.normals).observations
    head = seen(obs, "head0_left") & seen(obs, "head0_right")
    assert len(head) > 100
    assert not head & seen(obs, "ring4")  # 180 degrees round
    assert head & seen(obs, "ring1")  # the neighbour shares some
    assert len(obs.cameras) == 9
    centres = np.array([c.centre for c in drawn.rig.cameras])
    middle = centres.mean(axis=0)
    assert np.ptp(np.linalg.norm((centres - middle)[:, [0, 2]], axis=1)) < 0.4 * RING_RADIUS_M


def test_two_heads_and_a_taped_pair():
    heads = family("two_heads", seed=2).rig
    ids = [c.id for c in heads.cameras]
    assert ids[:4] == ["head0_left", "head0_right", "head1_left", "head1_right"]
    second = np.linalg.norm(heads.cameras[3].centre - heads.cameras[2].centre)
    assert second == pytest.approx(HEAD_BASELINE_M)
    assert [(b.a, b.b, b.baseline_m, b.sigma_m) for b in heads.baselines] == [
        ("head1_left", "head1_right", HEAD_BASELINE_M, 0.0)
    ]
    assert observe(heads, seed=2).observations.baselines == heads.baselines
    taped = family("tape_pair", seed=2).rig
    angle = np.degrees(np.arccos(np.clip(np.trace(taped.cameras[1].R) / 2 - 0.5, -1, 1)))
    assert 30 < angle < 60 and 1.2 < taped.baseline_m < 1.9  # 45 degrees round a 2 m ring
    assert taped.stereo.sigma_m == TAPE_SIGMA_M and taped.baselines == ()


def test_wide_lenses_fill_the_image_where_distortion_matters():
    drawn = family("wide", seed=3)
    left = drawn.rig.cameras[0]
    assert left.dist[0] < -0.2 and left.K[0, 0] < 600
    obs = observe(drawn.rig, noise_px=0.0, seed=3, normals=drawn.normals).observations
    uv = obs.uv[obs.cam_index == 0]
    radius = np.hypot(uv[:, 0] - left.K[0, 2], uv[:, 1] - left.K[1, 2])
    assert np.percentile(radius, 90) > 0.8 * left.width / 2


def test_the_narrow_ring_and_the_facade_are_the_real_scenes_they_model():
    ring = family("narrow_ring", seed=2)
    centres = np.array([c.centre for c in ring.rig.cameras])
    assert len(centres) == 12 and ring.given == ("cam00", "cam01")
    middle = centres.mean(axis=0)
    assert np.allclose(np.linalg.norm((centres - middle)[:, [0, 2]], axis=1), NARROW_RING_RADIUS_M, rtol=0.1)
    assert 0.09 < ring.rig.baseline_m < 0.12  # neighbours 30 degrees apart
    f = ring.rig.cameras[0].K[0, 0]
    assert 22 < np.degrees(2 * np.arctan(ring.rig.cameras[0].width / 2 / f)) < 26  # 24 degree lenses
    face = family("facade", seed=2)
    depths = np.concatenate([(face.rig.points @ c.R.T + c.t)[:, 2] for c in face.rig.cameras])
    assert depths.min() > 15 and np.median(depths) < 35  # 19-31 m away, relief included
    assert 1.5 < face.rig.baseline_m < 2.5 and face.rig.cameras[0].width == 3072


@pytest.mark.parametrize("name", HARD_FAMILIES)
def test_camnet_is_right_within_its_sigmas_on_the_modelled_scenes(name):
    """With clean simulated tracks the failures of the real scenes do not come back: every camera placed,
    the scale and every focal length within 3 of their reported sigmas."""
    drawn = family(name, seed=0)
    cal = calibrate(observe_family(drawn, seed=0)).calibration
    assert len(cal.cameras) == len(drawn.rig.cameras)
    errors = compare(cal, drawn.rig.cameras, drawn.rig.points)
    assert abs(errors.scale_rel) < 3 * errors.scale_sigma_rel
    for camera in errors.cameras:
        assert abs(camera.focal_rel) < 3 * camera.focal_sigma_rel or camera.focal_sigma_rel == 0


def test_outliers_fall_on_points_some_camera_sees():
    drawn = family("narrow_ring", seed=1)
    sim = observe(drawn.rig, noise_px=0.5, seed=1, normals=drawn.normals, outlier_fraction=0.3)
    assert sim.outlier_obs.sum() == round(0.3 * len(drawn.rig.points))
