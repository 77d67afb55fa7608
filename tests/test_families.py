"""The simulated real-rig families: what they are said to be."""

import numpy as np
import pytest

from camnet.sim.families import FAMILIES, HEAD_BASELINE_M, RING_RADIUS_M, TAPE_SIGMA_M, family
from camnet.sim.simulate import observe


def seen(observations, camera_id: str) -> set[int]:
    m = observations.index_of(camera_id)
    return set(observations.track_ids[observations.track_index[observations.cam_index == m]].tolist())


@pytest.mark.parametrize("name", FAMILIES)
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
