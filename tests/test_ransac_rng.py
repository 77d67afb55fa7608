"""camnet's RANSAC calls give the same result whatever drew from OpenCV's random state before, in any thread.

OpenCV's RANSAC and LMedS registrators (findFundamentalMat, findEssentialMat,
solvePnPRansac) sample with an RNG of their own seeded with a constant, and
USAC with its parameters' fixed state; none draws from cv::theRNG (the
thread's, which cv2.setRNGSeed seeds and the renderer's noise moves). So no
call needs seeding. These tests keep it so across OpenCV versions.
"""

import concurrent.futures

import cv2
import numpy as np
import pytest

from camnet.matching.features import MatcherConfig, ransac_fundamental
from camnet.model.resection import resect
from camnet.model.two_view import fundamental, relative_pose
from camnet.solve.start.warm import register_pnp


def scene(seed: int = 0, n: int = 150, outliers: float = 0.5):
    """Points (n, 3), centred pixels in a camera at the origin and in one 1 m to the side, half of them false."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (n, 3)) + [0.0, 0.0, 5.0]
    R = cv2.Rodrigues(np.array([0.02, -0.2, 0.01]))[0]
    t = np.array([1.0, 0.05, 0.1])
    xy1 = 800.0 * X[:, :2] / X[:, 2:] + rng.normal(0, 0.5, (n, 2))
    x2 = X @ R.T + t
    xy2 = 800.0 * x2[:, :2] / x2[:, 2:] + rng.normal(0, 0.5, (n, 2))
    false = rng.choice(n, int(outliers * n), replace=False)
    xy2[false] = rng.uniform(-500, 500, (len(false), 2))
    return X, xy1, xy2


def every_ransac_call(seed: int = 0) -> list[bytes]:
    X, xy1, xy2 = scene(seed)
    out = []
    F = fundamental(xy1, xy2, threshold_px=1.0)
    out += [F[0].tobytes(), F[1].tobytes()]
    pose = relative_pose(xy1, xy2, 800.0, 800.0, threshold_px=1.0)
    out += [pose.R.tobytes(), pose.t.tobytes(), pose.inliers.tobytes()]
    size = np.array([1280.0, 1024.0])
    F_px, inliers = ransac_fundamental(xy1 + size / 2, xy2 + size / 2, MatcherConfig())
    out += [F_px.tobytes(), inliers.tobytes()]
    R, C = register_pnp(X, xy2, np.arange(len(X)), 800.0, "cam", 2.0)
    out += [R.tobytes(), C.tobytes()]
    placed = resect(X, xy2, f_px=800.0, width_px=1280, threshold_px=2.0)
    assert not isinstance(placed, str), placed
    out += [np.float64(placed.f_px).tobytes(), placed.R.tobytes(), placed.C.tobytes(), placed.inliers.tobytes()]
    return out


def disturbed(seed: int) -> list[bytes]:
    cv2.setRNGSeed(seed)
    cv2.randu(np.empty(1000), 0.0, 1.0)
    return every_ransac_call()


@pytest.mark.parametrize("seed", [1, 12345])
def test_the_same_call_gives_the_same_result_after_the_global_rng_moved(seed):
    before = every_ransac_call()
    assert disturbed(seed) == before
    assert every_ransac_call() == before


def test_the_same_call_gives_the_same_result_in_other_threads():
    before = every_ransac_call()
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        results = list(pool.map(disturbed, range(4)))
    assert all(r == before for r in results)


@pytest.mark.filterwarnings("error")
def test_a_relative_pose_at_a_focal_length_no_pinhole_has_is_none_and_warns_nothing():
    _, xy1, xy2 = scene()
    assert relative_pose(xy1, xy2, -800.0, 800.0, threshold_px=1.0) is None
    assert relative_pose(xy1, xy2, 800.0, 0.0, threshold_px=1.0) is None
