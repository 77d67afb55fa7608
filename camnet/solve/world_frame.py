"""The world frame of a calibration found from its scene: the floor, the up direction and an origin on the floor.

Pure geometry on a metric calibration (camnet.model.calibration.Calibration: cameras ``x_cam = R X + t`` and
points in the left stereo camera's frame, metres), and `with_floor_frame`, which puts it on a solve's result. The
frame it gives is the contract's ``"floor"`` world frame: right-handed, Z up (against gravity), origin on the floor
below the centre of the capture volume, X horizontal toward the rig's front (the stereo pair, or the cameras
named); ``X_world = R X_left + t``.

The floor is the lowest plane of the point cloud whose normal lies within MAX_TILT_DEG of the cameras' own
"down" (the mean of their image y axes: cameras on a rig stand mostly upright), that lies below the cameras, that
has few points below it (nothing is seen through a floor: the top of a box has its sides below it, a table the
floor around it) and that is a layer (a slice through upright surfaces has as many points just above it). It is
found by RANSAC over such planes and refitted by least squares on its inliers (fit_floor). Without such a plane
the up direction is the cameras' down alone, the origin the centre of the capture volume, and
`WorldFrame.reason` says so.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from camnet.model.accuracy import angle_between_deg
from camnet.model.calibration import Calibration, FloorFrame
from camnet.model.camera import Camera
from camnet.model.observations import Observations
from camnet.solve.result import Result
from camnet.solve.uncertainty import Covariance

# The variance of a linear function of a calibration's points, given its gradient (n, 3) over them.
PointsVariance = Callable[[np.ndarray], float]

MAX_TILT_DEG = 30.0  # how far the floor's normal may lie from the cameras' up: a rig's cameras pitch, they stand
MIN_INLIERS = 30  # a floor is a plane that many points lie on
BELOW_SHARE = 0.05  # of the points, at most this many (wrong matches) may lie below a floor
THRESHOLD_REL = 0.01  # a point lies on a candidate plane within this share of the scene's size
RANSAC_SAMPLES = 500
RANSAC_POINTS = 5000  # the candidates are scored on at most this many points (a seeded draw), the fit on all
ROBUST_SIGMAS = 3.0  # the refit keeps points within this many robust sigmas of the plane
RIVAL_SHARE = 0.5  # another plane holding this share of the floor's points makes it ambiguous
LAYER_RATIO = 2.0  # a floor holds this many times the points in as thick a band just above it
MAX_LOWER = 5  # the floor is sought below the plane taken at most this many times (a table on a platform ...)


@dataclass(frozen=True)
class Floor:
    """The floor in the left camera's frame: the points X with ``up_left . X = -left_height_m``.

    up_left (3,): unit normal against gravity; left_height_m: the left camera centre's height above the floor (m);
    normal_sigma_deg: 1 sigma of the normal's tilt about its worse determined horizontal axis; height_sigma_m: 1
    sigma of left_height_m; inliers: the points the plane was fitted to; sigma_m: their RMS distance to it.
    """

    up_left: np.ndarray
    left_height_m: float
    normal_sigma_deg: float
    height_sigma_m: float
    inliers: int
    sigma_m: float

    def height_m(self, points_left: np.ndarray) -> np.ndarray:
        """Heights (n,) above the floor of points (n, 3) in the left camera's frame, metres."""
        return np.asarray(points_left, dtype=float).reshape(-1, 3) @ self.up_left + self.left_height_m


@dataclass(frozen=True)
class WorldFrame:
    """A world frame from the scene: ``X_world = R @ X_left + t`` (metres), Z up, X toward the rig's front.

    floor: None where the scene shows none; then `reason` says why, the up direction is the cameras' down alone and
    the origin is the centre of the capture volume.
    """

    R: np.ndarray
    t: np.ndarray
    floor: Floor | None
    reason: str = ""
    ambiguity: str = ""  # another plane could be the floor (PlaneFit.ambiguity)

    @property
    def up_left(self) -> np.ndarray:
        """The up direction (3,) in the left camera's frame."""
        return self.R[2].copy()

    def to_world(self, points_left: np.ndarray) -> np.ndarray:
        """Points (n, 3) of the left camera's frame in the world frame."""
        return np.asarray(points_left, dtype=float).reshape(-1, 3) @ self.R.T + self.t


def camera_down(rotations: np.ndarray) -> np.ndarray:
    """The cameras' mean "down" (3,), unit, in the world of their rotations (m, 3, 3), ``x_cam = R X + t``.

    A camera's down is its image y axis (pixel rows grow downwards), ``R^T [0, 1, 0]``: the second row of R.
    """
    down = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)[:, 1, :].sum(axis=0)
    norm = np.linalg.norm(down)
    if norm < 1e-9:
        raise ValueError("the cameras' image y axes cancel out: no camera points anywhere near down")
    return down / norm


def visible_counts(cameras: Sequence[Camera], points: np.ndarray) -> np.ndarray:
    """How many of `cameras` have each point (n, 3) in front of them and inside their image: (n,) int."""
    counts = np.zeros(len(points), dtype=int)
    for cam in cameras:
        uv = cam.project(points)
        counts += (np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5)
                   & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5))
    return counts


def capture_centre(cameras: Sequence[Camera], points: np.ndarray, *, least: int = 10) -> np.ndarray:
    """The centre of the capture volume (3,): the median of the points that the most cameras see.

    The points taken are those seen by at least c cameras, c the largest count that leaves `least` points (all of
    them where there are fewer); without points, the mean of the camera centres.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        return np.mean([c.centre for c in cameras], axis=0)
    counts = visible_counts(cameras, points)
    needed = np.sort(counts)[::-1][min(least, len(points)) - 1]
    return np.median(points[counts >= needed], axis=0)


def _planes(triples: np.ndarray, down: np.ndarray, max_tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (k, 3) pointing up (against `down`) and offsets (k,) (``n . X = d``) of the planes through
    `triples` (m, 3, 3) whose normal lies within max_tilt_deg of up; degenerate triples are left out."""
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals = normals[ok] / norms[ok, None]
    normals *= -np.sign(normals @ down)[:, None]
    keep = normals @ -down >= np.cos(np.radians(max_tilt_deg))
    normals = normals[keep]
    return normals, np.einsum("ij,ij->i", normals, triples[ok][keep, 0])


def _refit(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """The least-squares plane (unit normal against `up`'s side, offset) through points (n, 3)."""
    mean = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mean, full_matrices=False)
    normal = vt[2] if vt[2] @ up >= 0 else -vt[2]
    return normal, float(normal @ mean)


@dataclass(frozen=True)
class PlaneFit:
    """A floor plane fitted to points: ``normal . X = offset`` (normal unit, up), its inliers and their scatter.

    inliers (n,) bool: the points it was fitted to; sigma_m: their RMS distance to it (n - 3 degrees of freedom);
    axes (2, 3): orthonormal in-plane axes; tilt_cov (2, 2): the covariance (rad^2) of the normal's tilt about
    `axes` that the scatter alone leaves, sigma_m^2 S^-1 with S the inliers' 2x2 scatter about their mean along
    the plane.
    """

    normal: np.ndarray
    offset: float
    inliers: np.ndarray
    sigma_m: float
    axes: np.ndarray
    tilt_cov: np.ndarray
    ambiguity: str = ""  # another plane could be the floor: which, and that the lowest was taken
    # That plane's tilt from this one's normal (degrees) and its height over it (metres): the floor's sigmas cover it.
    rival_tilt_deg: float = 0.0
    rival_height_m: float = 0.0


def fit_floor(points: np.ndarray, down: np.ndarray, camera_centres: np.ndarray, *, seed: int = 0) -> PlaneFit | str:
    """The floor among points (n, 3) (metres, any frame), or why there is none.

    down (3,): the cameras' mean down (camera_down), the prior of the floor's normal; camera_centres (m, 3): the
    floor lies below their mean.

    Candidate planes through three points, their normal within MAX_TILT_DEG of up, are scored by the points within
    THRESHOLD_REL of the scene's size (the median distance of the points from the cameras' mean centre); a
    candidate that has more than BELOW_SHARE of the points below it (beyond that threshold), that does not lie
    below the cameras or that holds fewer than LAYER_RATIO times the points in as thick a band just above it (a
    slice through upright surfaces) is no floor. From the plane below the cameras holding the most points, lower
    planes holding MIN_INLIERS are sought among the points below the one taken, down to the lowest (at most
    MAX_LOWER times); it is refitted by least squares to its inliers, twice, the second time to those within
    ROBUST_SIGMAS of 1.4826 times the median absolute residual. Another plane that may be the floor holding
    RIVAL_SHARE of its points makes it ambiguous (PlaneFit.ambiguity, with that plane's tilt and height).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    down = np.asarray(down, dtype=float)
    up = -down / np.linalg.norm(down)
    centres = np.asarray(camera_centres, dtype=float).reshape(-1, 3)
    if len(points) < MIN_INLIERS:
        return f"the calibration has {len(points)} points, fewer than the {MIN_INLIERS} a floor needs"
    middle = centres.mean(axis=0)
    threshold = THRESHOLD_REL * float(np.median(np.linalg.norm(points - middle, axis=1)))
    rng = np.random.default_rng(seed)
    scored = points if len(points) <= RANSAC_POINTS else points[rng.choice(len(points), RANSAC_POINTS, replace=False)]
    per_scored = len(points) / len(scored)
    enough = MIN_INLIERS / per_scored  # the scored points a floor needs

    def candidates(pool: np.ndarray) -> tuple[np.ndarray, ...]:
        """Planes through triples of `pool`: normals, offsets, the scored points' heights over them, which lie on
        them, which lie below the cameras and which of those may be the floor (few points below them, a layer)."""
        normals, offsets = _planes(pool[rng.integers(len(pool), size=(RANSAC_SAMPLES, 3))], down, MAX_TILT_DEG)
        heights = scored @ normals.T - offsets
        on = np.abs(heights) <= threshold
        under_cameras = middle @ normals.T - offsets > threshold
        # A floor is a layer of points: a slice through upright surfaces has as many just above it.
        layer = on.sum(axis=0) >= LAYER_RATIO * ((heights > threshold) & (heights <= 3 * threshold)).sum(axis=0)
        valid = ((heights < -threshold).sum(axis=0) <= BELOW_SHARE * len(scored)) & under_cameras & layer
        return normals, offsets, heights, on, under_cameras, valid

    normals, offsets, heights, on, under_cameras, valid = candidates(scored)
    if len(normals) == 0:
        return f"no plane through the points lies within {MAX_TILT_DEG:g} degrees of the cameras' up"
    held = under_cameras & (on.sum(axis=0) >= enough)
    if not held.any():
        return (f"no plane within the tilt the cameras allow lies below them holding the {MIN_INLIERS} points a "
                "floor needs")
    # The plane holding the most points below the cameras, then, while there is one, a lower plane found among the
    # points below it: the one holding the most of those that may be the floor, else the one holding the most (a
    # table top or a platform may show more of itself than of the floor, and a box's top has its sides below).
    chosen = int(np.argmax(np.where(held, on.sum(axis=0), -1)))
    for _ in range(MAX_LOWER):
        under = scored[heights[:, chosen] < -threshold]
        if len(under) < max(enough, 3):
            break
        more = candidates(under)
        normals, offsets = np.concatenate([normals, more[0]]), np.concatenate([offsets, more[1]])
        heights, on = np.hstack([heights, more[2]]), np.hstack([on, more[3]])
        under_cameras, valid = np.concatenate([under_cameras, more[4]]), np.concatenate([valid, more[5]])
        median, apart = _apart(on, heights, chosen, threshold)
        lower = apart & (median < 0) & under_cameras & (on.sum(axis=0) >= enough)
        if not lower.any():
            break
        chosen = int(np.argmax(np.where(lower, on.sum(axis=0) + len(scored) * valid, -1)))
    if not valid[chosen]:
        return "no plane within the tilt the cameras allow lies below the cameras with the scene above it"
    median, apart = _apart(on, heights, chosen, threshold)
    inliers = on.sum(axis=0)
    rivals = valid & apart & (inliers >= max(enough, RIVAL_SHARE * inliers[chosen]))
    ambiguity, rival_tilt_deg, rival_height_m = "", 0.0, 0.0
    if rivals.any():
        rival = int(np.argmax(np.where(rivals, inliers, -1)))
        rival_tilt_deg = angle_between_deg(normals[rival], normals[chosen])
        rival_height_m = float(median[rival])
        ambiguity = (f"the floor is ambiguous: another plane {abs(median[rival]):.2f} m "
                     f"{'above' if median[rival] > 0 else 'below'} it, tilted {rival_tilt_deg:.0f} degrees from it, "
                     f"holds about {int(inliers[rival] * per_scored)} points to its "
                     f"{int(inliers[chosen] * per_scored)}; the lowest was taken, and the floor's sigmas cover both")
    normal, offset = normals[chosen], offsets[chosen]
    keep = np.abs(points @ normal - offset) <= threshold
    normal, offset = _refit(points[keep], up)
    residuals = points @ normal - offset
    robust = 1.4826 * float(np.median(np.abs(residuals[keep] - np.median(residuals[keep]))))
    keep = np.abs(residuals) <= min(threshold, max(ROBUST_SIGMAS * robust, 1e-9))
    n = int(keep.sum())
    if n < MIN_INLIERS:
        return f"the floor's refit keeps {n} points, fewer than the {MIN_INLIERS} a floor needs"
    normal, offset = _refit(points[keep], up)
    if np.degrees(np.arccos(np.clip(normal @ up, -1.0, 1.0))) > MAX_TILT_DEG:
        return f"the refitted plane lies more than {MAX_TILT_DEG:g} degrees from the cameras' up"
    on_floor = points[keep]
    s = float(np.sqrt(np.sum((on_floor @ normal - offset) ** 2) / max(n - 3, 1)))
    axes = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2].T  # any orthonormal pair across the normal
    along = (on_floor - on_floor.mean(axis=0)) @ axes.T
    return PlaneFit(normal, offset, keep, s, axes, s**2 * np.linalg.inv(along.T @ along), ambiguity, rival_tilt_deg,
                    rival_height_m)


def _apart(on: np.ndarray, heights: np.ndarray, chosen: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(median, apart): per candidate plane, the median height of its inliers over plane `chosen`, and whether it is
    another plane: fewer than half its inliers are the chosen one's and that median is beyond 3 thresholds.

    on (n, k): which scored points lie on which candidate; heights (n, k): their heights over it.
    """
    median = np.nanmedian(np.where(on, heights[:, [chosen]], np.nan), axis=0)  # every plane holds its 3 points
    shared = (on & on[:, [chosen]]).sum(axis=0) / on.sum(axis=0)
    return median, (shared < 0.5) & (np.abs(median) > 3 * threshold)


def floor_gradients(fit: PlaneFit, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gradients (each (n, 3)) of the fitted floor's tilt about `fit.axes[0]`, about `fit.axes[1]` (radians) and of
    the left camera's height above it (m), with respect to points (n, 3) (left camera's frame; zero off the inliers).

    The least-squares plane's heights over its inliers' in-plane coordinates q (about their mean) have the slopes
    b = S^-1 sum(q_i h_i) and, at the origin q_0, the height mean(h) + q_0 . b; a point moved by dX moves its
    height by normal . dX.
    """
    on_floor = points[fit.inliers]
    mean = on_floor.mean(axis=0)
    q = (on_floor - mean) @ fit.axes.T
    slopes = q @ np.linalg.inv(q.T @ q)  # (n_in, 2): row i is S^-1 q_i
    q0 = -mean @ fit.axes.T
    out = [np.zeros_like(points) for _ in range(3)]
    out[0][fit.inliers] = slopes[:, :1] * fit.normal
    out[1][fit.inliers] = slopes[:, 1:] * fit.normal
    out[2][fit.inliers] = -(1.0 / len(on_floor) + slopes @ q0)[:, None] * fit.normal
    return out[0], out[1], out[2]


def floor_sigmas(fit: PlaneFit, points: np.ndarray, *, variance: PointsVariance | None = None,
                 scale_rel: float = 0.0) -> Floor:
    """The Floor of a plane fitted to points (n, 3) in the left camera's frame, with its sigmas.

    variance: the solve's covariance of the points, as the variance of a linear function of them given its
    gradient (n, 3) (points_variance); it holds the errors every floor point shares (the network's orientation
    and scale against the left camera). The scatter about the plane gives a second opinion, which also holds a
    floor that is not flat: the tilt's covariance is the fit's (PlaneFit.tilt_cov) and the left camera's height's
    variance sigma_m^2 / n plus the tilt's through the in-plane distance from the inliers' mean to the left camera
    plus (scale_rel times the height)^2. Of the two, the larger is reported, each (normal_sigma_deg: the square
    root of the tilt covariance's larger eigenvalue); the scatter's alone where the covariance leaves a variance
    infinite (a direction the observations do not fix).
    """
    n = int(fit.inliers.sum())
    lever = -points[fit.inliers].mean(axis=0) @ fit.axes.T  # the left camera (the origin) from the inliers' mean
    height = -fit.offset
    tilt_cov = fit.tilt_cov
    height_var = fit.sigma_m**2 / n + float(lever @ tilt_cov @ lever) + (scale_rel * height) ** 2
    if variance is not None:
        g0, g1, gh = floor_gradients(fit, points)
        v0, v1, v01, vh = variance(g0), variance(g1), variance(g0 + g1), variance(gh)
        solved = np.array([[v0, (v01 - v0 - v1) / 2], [(v01 - v0 - v1) / 2, v1]])
        if np.all(np.isfinite(solved)) and np.linalg.eigvalsh(solved)[-1] > np.linalg.eigvalsh(tilt_cov)[-1]:
            tilt_cov = solved
        if np.isfinite(vh):
            height_var = max(height_var, vh)
    return Floor(
        up_left=fit.normal,
        left_height_m=float(height),
        normal_sigma_deg=float(np.degrees(np.sqrt(np.linalg.eigvalsh(tilt_cov)[-1]))),
        height_sigma_m=float(np.sqrt(height_var)),
        inliers=n,
        sigma_m=fit.sigma_m,
    )


def points_variance(cov: Covariance, kept: np.ndarray) -> PointsVariance:
    """The variance of a linear function of a calibration's points under its solve's covariance: the calibration
    reports the solve's points `kept` (the solve's (N,) bool), the function's gradient is over those, (n, 3)."""
    kept = np.asarray(kept, dtype=bool)

    def variance(gradient: np.ndarray) -> float:
        full = np.zeros((len(kept), 3))
        full[kept] = gradient
        return cov.variance(None, full)

    return variance


def _horizontal(direction: np.ndarray, up: np.ndarray) -> np.ndarray | None:
    """`direction` with its component along `up` removed, unit; None where it is (nearly) vertical."""
    flat = direction - (direction @ up) * up
    norm = np.linalg.norm(flat)
    return flat / norm if norm > 1e-6 * max(np.linalg.norm(direction), 1e-12) else None


def frame_from(up: np.ndarray, origin: np.ndarray, toward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of ``X_world = R X + t``: Z along `up`, origin at `origin`, X horizontal toward the point `toward`.

    Where `toward` lies straight above or below the origin, X is horizontal away from the left camera's view
    (its -z axis; its x axis where that is vertical), all in the frame of the inputs, the left camera's.
    """
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    for direction in (np.asarray(toward, dtype=float) - origin, np.array([0.0, 0.0, -1.0]), np.array([1.0, 0, 0])):
        x = _horizontal(direction, up)
        if x is not None:
            break
    R = np.stack([x, np.cross(up, x), up])
    return R, -R @ np.asarray(origin, dtype=float)


def world_frame(cal: Calibration, *, x_toward: Sequence[str] = (), variance: PointsVariance | None = None,
                seed: int = 0) -> WorldFrame:
    """The world frame of a calibration in its left camera's frame, found from its scene (module docstring).

    x_toward: camera ids the X axis points toward (horizontally, from the origin to their centres' mean); none: the
    left camera (the origin of the calibration's frame). variance: the solve's covariance of the calibration's
    points (points_variance); without it the floor's sigmas are those of its scatter alone, and miss what all of
    its points share.
    """
    ids = [c.id for c in cal.cameras]
    unknown = [i for i in x_toward if i not in ids]
    if unknown:
        raise ValueError(f"x_toward names camera {unknown[0]!r}, which the calibration lacks; "
                         f"name one of {', '.join(ids)}")
    whose = "the cameras' own down direction"
    try:
        down = camera_down(np.array([c.R for c in cal.cameras]))
    except ValueError:
        down = np.array([0.0, 1.0, 0.0])  # the left camera's image y axis, in its own frame
        whose = "the left camera's own down direction (the cameras' cancel out)"
    centres = np.array([c.centre for c in cal.cameras])
    fit = fit_floor(cal.points, down, centres, seed=seed)
    centre = capture_centre(cal.cameras, cal.points)
    toward = centres[[ids.index(i) for i in x_toward]].mean(axis=0) if x_toward else np.zeros(3)
    if isinstance(fit, str):
        R, t = frame_from(-down, centre, toward)
        return WorldFrame(R, t, None, f"no floor in view ({fit}): up is {whose}, the origin the centre of the "
                                      "capture volume")
    scale = cal.uncertainty.scale_rel.value if cal.uncertainty is not None else None
    floor = floor_sigmas(fit, cal.points, variance=variance, scale_rel=scale or 0.0)
    if fit.ambiguity:  # the other plane within two sigmas, as a rival solution is (camnet.solve.report.rivals)
        floor = replace(floor, normal_sigma_deg=float(np.hypot(floor.normal_sigma_deg, fit.rival_tilt_deg / 2)),
                        height_sigma_m=float(np.hypot(floor.height_sigma_m, fit.rival_height_m / 2)))
    origin = centre - floor.height_m(centre)[0] * floor.up_left
    R, t = frame_from(floor.up_left, origin, toward)
    return WorldFrame(R, t, floor, ambiguity=fit.ambiguity)


def floor_frame(frame: WorldFrame) -> FloorFrame:
    """What a calibration written in `frame` says of it (Calibration.floor_frame)."""
    if frame.floor is None:
        return FloorFrame(frame.R, frame.t, reason=frame.reason)
    return FloorFrame(frame.R, frame.t, frame.floor.normal_sigma_deg, frame.floor.height_sigma_m,
                      ambiguity=frame.ambiguity)


def with_floor_frame(result: Result, obs: Observations) -> Result:
    """`result` of solving `obs` with its calibration to be written in the frame found from its scene, X toward
    the stereo pair; the floor's sigmas from the solve's covariance (a second opinion widens them as it widens
    every sigma: camnet.solve.halves). Where the scene shows no floor, or another plane could be it, a warning
    says so."""
    cal = result.calibration
    variance = None
    if result.covariance is not None:
        kept = np.isin(obs.track_ids[np.asarray(result.track_rows)], cal.point_ids)
        variance = points_variance(result.covariance, kept)
    pair = tuple(c for c in (obs.stereo.left, obs.stereo.right) if c in {k.id for k in cal.cameras})
    frame = world_frame(cal, x_toward=pair, variance=variance)
    cal = replace(cal, floor_frame=floor_frame(frame)).warned(*(w for w in (frame.reason, frame.ambiguity) if w))
    return replace(result, calibration=cal)
