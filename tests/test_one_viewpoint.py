"""Two views from one viewpoint (a pure rotation between them): no start, and no point from them alone."""

import numpy as np

from camnet.model.projection import look_at
from camnet.model.triangulation import triangulate_missing
from camnet.model.two_view import homography_explains


def rotation(centre, target) -> np.ndarray:
    return look_at(np.asarray(centre, float), np.asarray(target, float))[0]

F_PX = 800.0


def scene(seed: int = 0) -> np.ndarray:
    """Points of an object 0.3 m across, 2 m ahead of the origin (metres)."""
    return np.random.default_rng(seed).uniform([-0.15, -0.15, 1.85], [0.15, 0.15, 2.15], (200, 3))


def view(X: np.ndarray, R: np.ndarray, C: np.ndarray, noise_px: float, rng) -> np.ndarray:
    """Centred pixels of X seen by a camera x_cam = R (X - C) at F_PX, with Gaussian noise."""
    xc = (X - C) @ R.T
    return F_PX * xc[:, :2] / xc[:, 2:3] + rng.normal(0.0, noise_px, (len(X), 2))


def test_a_homography_explains_a_turned_view_from_one_viewpoint_and_not_a_baseline():
    rng = np.random.default_rng(1)
    X = scene()
    centre = np.zeros(3)
    first = view(X, rotation(centre, [0.0, 0.0, 2.0]), centre, 0.3, rng)
    turned = view(X, rotation(centre, [0.1, 0.05, 2.0]), centre, 0.3, rng)
    beside = np.array([0.5, 0.0, 0.0])
    moved = view(X, rotation(beside, [0.0, 0.0, 2.0]), beside, 0.3, rng)
    assert homography_explains(first, turned, threshold_px=4.0)
    assert not homography_explains(first, moved, threshold_px=4.0)


def test_tracks_seen_from_one_viewpoint_alone_get_no_point_and_the_others_do():
    rng = np.random.default_rng(2)
    X = scene()
    target = np.array([0.0, 0.0, 2.0])
    centres = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])  # the first two: one viewpoint
    R = np.stack([rotation(centres[0], target), rotation(centres[1], target + [0.1, 0.0, 0.0]),
                  rotation(centres[2], target)])
    uv = [view(X, R[m], centres[m], 0.3, rng) for m in range(3)]
    # The first 100 tracks are seen by the two views from one viewpoint alone, the rest by all three.
    seen = np.ones((len(X), 3), dtype=bool)
    seen[:100, 2] = False
    rows = np.full((len(X), 3), -1)
    t_idx, c_idx = np.nonzero(seen)
    rows[t_idx, c_idx] = np.arange(len(t_idx))
    xy = np.stack([uv[c][t] for t, c in zip(t_idx, c_idx, strict=True)])
    points = np.full((len(X), 3), np.nan)

    triangulate_missing([0, 1, 2], xy, rows, np.full(3, F_PX), R, centres, points, np.ones(3, dtype=bool))

    assert np.all(np.isnan(points[:100]))
    assert np.all(np.isfinite(points[100:]))
    assert np.median(np.linalg.norm(points[100:] - X[100:], axis=1)) < 0.01
