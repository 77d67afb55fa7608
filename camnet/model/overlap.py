"""Which cameras of a calibrated rig see the same part of the scene: the pairs worth matching.

Conventions: a world point X (metres) is ``x_cam = R X + t`` in a camera
(axes x right, y down, z forward), its depth is z_cam (m); pixels and lens
models as in `camnet.model.projection`. A camera's image is taken as the
box of its undistorted border in normalised coordinates (x/z, y/z): for a
distorted lens this box is a little larger than the image, so that a pair is
kept rather than missed.

Two cameras overlap when their frusta, each cut to the depth range of the
scene points it sees, share volume, and their optical axes are close enough
for features to be matched across the change of viewpoint: cameras on a ring
all look at its centre, but the one opposite sees the other side of it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from camnet.model.camera import Camera

BORDER_SAMPLES = 16  # pixels along each image side whose undistorted rays bound the image
MIN_PARTNERS = 2  # a camera keeps at least this many partners (where it has as many qualified)


def image_bounds(camera: Camera) -> np.ndarray:
    """(4,): x_min, x_max, y_min, y_max of the camera's image border in normalised coordinates (x/z, y/z)."""
    w, h = camera.width - 1.0, camera.height - 1.0
    s = np.linspace(0.0, 1.0, BORDER_SAMPLES)
    border = np.concatenate([np.column_stack([s * w, np.zeros_like(s)]), np.column_stack([s * w, np.full_like(s, h)]),
                             np.column_stack([np.zeros_like(s), s * h]), np.column_stack([np.full_like(s, w), s * h])])
    xy = camera.normalised(border)
    return np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()])


def _in_image(points_cam: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Boolean (n,): camera-frame points (n, 3) in front of the camera and inside `bounds` (image_bounds)."""
    z = points_cam[:, 2]
    front = z > 1e-9
    x = np.where(front, points_cam[:, 0] / np.where(front, z, 1.0), np.inf)
    y = np.where(front, points_cam[:, 1] / np.where(front, z, 1.0), np.inf)
    return front & (x >= bounds[0]) & (x <= bounds[1]) & (y >= bounds[2]) & (y <= bounds[3])


def depth_ranges(cameras: Sequence[Camera], points_world: np.ndarray, *,
                 percentiles: tuple[float, float] = (1.0, 99.0)) -> np.ndarray:
    """(M, 2): near and far depth (m) of the world points (N, 3) each camera sees; NaN where it sees none.

    A camera "sees" a point in front of it inside its image (occlusion is not
    known); near and far are the given percentiles of those points' depths.
    """
    points_world = np.asarray(points_world, dtype=float).reshape(-1, 3)
    out = np.full((len(cameras), 2), np.nan)
    for i, cam in enumerate(cameras):
        points_cam = points_world @ cam.R.T + cam.t
        seen = _in_image(points_cam, image_bounds(cam))
        if seen.any():
            out[i] = np.percentile(points_cam[seen, 2], percentiles)
    return out


def frustum_overlap(cameras: Sequence[Camera], ranges_m: np.ndarray, *, grid: int = 8, layers: int = 4) -> np.ndarray:
    """(M, M): the part of camera a's frustum (within its depth range) that camera b sees within its own.

    `ranges_m` (M, 2): near and far depth (m) per camera (`depth_ranges`).
    Camera a's frustum is sampled on a `grid` x `grid` grid of pixels times
    `layers` depths from near to far; entry [a, b] is the fraction of those
    samples inside b's image at a depth within b's range. The diagonal is 1;
    rows and columns of a camera with no finite range are NaN.
    """
    m = len(cameras)
    ranges_m = np.asarray(ranges_m, dtype=float).reshape(m, 2)
    known = np.isfinite(ranges_m).all(axis=1)
    bounds = [image_bounds(c) for c in cameras]
    overlap = np.full((m, m), np.nan)
    for a, cam in enumerate(cameras):
        if not known[a]:
            continue
        u = np.linspace(0.0, cam.width - 1.0, grid)
        v = np.linspace(0.0, cam.height - 1.0, grid)
        uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
        rays = np.column_stack([cam.normalised(uv), np.ones(len(uv))])
        depths = np.linspace(ranges_m[a, 0], ranges_m[a, 1], layers)
        samples_cam = (rays[None, :, :] * depths[:, None, None]).reshape(-1, 3)
        samples_world = (samples_cam - cam.t) @ cam.R  # X = R^T (x_cam - t)
        for b, other in enumerate(cameras):
            if not known[b]:
                continue
            in_b = samples_world @ other.R.T + other.t
            inside = _in_image(in_b, bounds[b]) & (in_b[:, 2] >= ranges_m[b, 0]) & (in_b[:, 2] <= ranges_m[b, 1])
            overlap[a, b] = inside.mean()
        overlap[a, a] = 1.0
    return overlap


def axis_angles_deg(cameras: Sequence[Camera]) -> np.ndarray:
    """(M, M): angle (degrees) between the optical axes (the rows R[2], in the world) of each pair."""
    axes = np.array([c.R[2] for c in cameras], dtype=float).reshape(-1, 3)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))


def overlapping_pairs(cameras: Sequence[Camera], points_world: np.ndarray, *, min_overlap: float = 0.05,
                      max_axis_angle_deg: float = 75.0, neighbours: int = 4) -> list[tuple[int, int]]:
    """Index pairs (i < j) of `cameras` worth matching, from their poses and the scene's points (N, 3).

    A pair qualifies when either camera sees at least `min_overlap` of the
    other's frustum in the scene's depth range (`frustum_overlap`) and their
    axes are at most `max_axis_angle_deg` apart. Qualified pairs are taken best
    first (overlap times the cosine of the axis angle) while both cameras have
    fewer than `neighbours` partners, so that there are at most
    neighbours * M / 2 pairs: linear in M. (Each camera's own best
    `neighbours`, united, made 41 pairs of the 16 cameras of an arc round
    one object, where every camera is some camera's best.) A camera whose
    qualified partners filled first keeps its best `MIN_PARTNERS` anyway.
    A camera that sees no point has no pair here (the caller matches it
    with every camera).
    """
    if not 0.0 <= min_overlap <= 1.0 or neighbours < 1:
        raise ValueError(f"expected min_overlap in [0, 1] and neighbours >= 1, got {min_overlap}, {neighbours}")
    overlap = frustum_overlap(cameras, depth_ranges(cameras, points_world))
    shared = np.fmax(overlap, overlap.T)  # NaN only where both are unknown
    angles = axis_angles_deg(cameras)
    qualified = np.nan_to_num(shared) >= min_overlap
    qualified &= angles <= max_axis_angle_deg
    np.fill_diagonal(qualified, False)
    score = np.where(qualified, np.nan_to_num(shared) * np.cos(np.radians(angles)), -np.inf)
    first, second = np.nonzero(np.triu(qualified, 1))
    order = np.lexsort((second, first, -score[first, second]))  # best first; ties by index, for repeatability
    degree = np.zeros(len(cameras), dtype=int)
    pairs: set[tuple[int, int]] = set()
    for a, b in zip(first[order].tolist(), second[order].tolist(), strict=True):
        if degree[a] < neighbours and degree[b] < neighbours:
            pairs.add((a, b))
            degree[[a, b]] += 1
    # A camera left with one partner or none (its others filled first) ends a chain: give it a second.
    least = min(MIN_PARTNERS, neighbours)
    for a in np.flatnonzero(degree < least).tolist():
        for b in np.argsort(-score[a], kind="stable")[:np.count_nonzero(qualified[a])].tolist():
            if degree[a] >= least:
                break
            if (min(a, b), max(a, b)) not in pairs:
                pairs.add((min(a, b), max(a, b)))
                degree[[a, b]] += 1
    return sorted(pairs)
