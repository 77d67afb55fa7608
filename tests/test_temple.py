"""The Middlebury temple ring end to end: real images, matched and calibrated with one known distance.

Sixteen views of a 10 cm object from a ring 0.6 m away, 23 degrees between
neighbours, a 24 degree field of view, and two views (templeSR0001 and
templeSR0011) taken from one viewpoint: 645 tracks are seen by those two
alone. Their points have no depth (no parallax): left in, they hold the
adjustment to its iteration limit. All sixteen views: the failure needs the
whole ring (on eight views round 0001 and 0011 the adjustment converges with
them).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from camnet.datasets.published import compare, in_frame_of
from camnet.datasets.temple import image_path, read_cameras
from camnet.matching.pipeline import observations_from_frame_sets, with_known_intrinsics
from camnet.model.camera import CameraInfo
from camnet.model.observations import Stereo
from camnet.solve import Options, calibrate
from camnet.solve.report.verdict import Level, judge
from tests._groundtruth import TEMPLE_ROOT, require

VIEWS = [f"templeSR{k:04d}" for k in range(1, 17)]
LEFT, RIGHT = "templeSR0007", "templeSR0008"
# With nothing known (benchmarks/bench_temple.py, docs/benchmarks.md "Real images: the temple ring"), every focal
# length lies within about 11% of the published one, some of them beyond 3 of their reported sigmas (the principal
# points, freed, trade with the poses at this narrow field of view), a known shortfall that section states; the
# bound leaves a margin for other platforms' SIFT. The principal points move far from the image centre, so the
# solve says its scale has no linear sigma and names each such camera. The scale then lies anywhere along a
# nearly flat valley, a few percent off with this pair (10% with the other neighbour pair); 6% leaves a margin.
FOCAL_BOUND_REL = 0.20
FOCAL_BOUND_SIGMAS = 7.0
SCALE_BOUND_REL = 0.06
# With every view's published K: every view within about 3 of its reported sigmas of its published centre (the
# common scale error is most of it) and of its rotation; 4 leaves a margin. A view resected at its neighbour's
# viewpoint sits tens of sigmas off (docs/benchmarks.md, "Real images: the temple ring").
POSE_BOUND_SIGMAS = 4.0
# What these tests hold is the solve's own finding (no linear scale sigma; a moved principal point rated poor), not
# the second opinion's widening: they ask none, at a third of the time.
ALONE = Options(halves=False)


@pytest.fixture(scope="module")
def ring():
    """(observations, published cameras in the left view's frame): all sixteen views matched as one frame set."""
    root = require(TEMPLE_ROOT)
    published = in_frame_of(read_cameras(root), LEFT)
    baseline_m = float(np.linalg.norm(published[RIGHT].centre - published[LEFT].centre))
    images = {v: cv2.imread(str(image_path(root, v)), cv2.IMREAD_UNCHANGED) for v in VIEWS}
    obs = observations_from_frame_sets([images], cameras=[CameraInfo(v, 640, 480) for v in VIEWS],
                                       stereo=Stereo(LEFT, RIGHT, baseline_m))
    return obs, published


def test_with_the_published_K_every_view_kept_is_within_its_sigmas_of_its_published_pose(ring):
    obs, published = ring
    obs = with_known_intrinsics(obs, published, given=("K",))

    result = calibrate(obs)

    assert result.converged, result.reason
    report = result.calibration.report
    placed = {c.id for c in result.calibration.cameras}
    assert placed | set(report.cameras_left_out) == set(VIEWS)
    assert len(placed) >= 14, report.cameras_left_out  # a margin below all sixteen
    vs = compare(result.calibration, obs, published, depth_range_m=(0.3, 1.0))
    for c in vs.cameras:
        if c.id == LEFT:
            continue
        assert c.centre_mm <= POSE_BOUND_SIGMAS * c.centre_sigma_mm, (c.id, c.centre_mm, c.centre_sigma_mm)
        assert c.rotation_deg <= POSE_BOUND_SIGMAS * c.rotation_sigma_deg, (c.id, c.rotation_deg,
                                                                          c.rotation_sigma_deg)


def test_the_ring_with_two_views_from_one_viewpoint_calibrates_near_the_published_cameras(ring, record_property):
    obs, published = ring

    result = calibrate(obs, ALONE)

    assert result.converged, result.reason
    report = result.calibration.report
    placed = {c.id for c in result.calibration.cameras}
    # A view left out is named, with its reason, among the warnings.
    assert placed | set(report.cameras_left_out) == set(VIEWS)
    for cam_id in report.cameras_left_out:
        assert any(w.startswith(f"camera {cam_id} left out:") for w in report.warnings)
    vs = compare(result.calibration, obs, published, depth_range_m=(0.3, 1.0))
    record_property("scale", {"error_rel": vs.distance_rel, "sigma_rel": vs.scale_sigma_rel,
                              "points": vs.distance_points})
    record_property("focal", {c.id: (round(c.focal_rel, 4), round(c.focal_sigma_rel, 4)) for c in vs.cameras})
    assert vs.distance_points >= 100
    assert abs(vs.distance_rel) <= SCALE_BOUND_REL, vs.distance_rel
    # Not wrong in silence: the focal lengths are off by up to 4.6 sigmas, so no scale sigma, and why.
    scale = report.uncertainty.scale_rel
    assert scale.value is None and "principal points" in scale.reason, scale
    # Nobody gave them: they moved from the image centre, where they were guessed.
    assert "of the image from the image centre" in scale.reason and "given" not in scale.reason, scale
    for cam_id in (LEFT, RIGHT):
        assert any(w.startswith(f"camera {cam_id}: its principal point, freed, moved") and "from the image centre" in w
                   for w in report.warnings)
    for c in vs.cameras:
        assert c.focal_sigma_rel > 0, c.id
        assert abs(c.focal_rel) <= min(FOCAL_BOUND_REL, FOCAL_BOUND_SIGMAS * c.focal_sigma_rel), (c.id, c.focal_rel,
                                                                                                 c.focal_sigma_rel)


def test_with_the_pairs_K_every_camera_beyond_its_sigmas_is_rated_poor(ring):
    obs, published = ring
    obs = with_known_intrinsics(obs, {v: published[v] for v in (LEFT, RIGHT)}, given=("K",))

    calibration = calibrate(obs, ALONE).calibration

    levels = {c.camera: c.level for c in judge(calibration).cameras}
    vs = compare(calibration, obs, published, depth_range_m=(0.3, 1.0))
    beyond = [c.id for c in vs.cameras if abs(c.focal_rel) > 3 * c.focal_sigma_rel
              or c.rotation_deg > 3 * c.rotation_sigma_deg]
    # The freed principal points of this narrow ring trade with the poses: some camera ends beyond its sigmas,
    # and each such one is rated poor for the principal point that moved where no lens's lies.
    assert beyond
    for cam_id in beyond:
        assert levels[cam_id] == Level.POOR, (cam_id, levels[cam_id])
        assert cam_id in calibration.report.far_principal_points, cam_id
