"""Features and pairwise matching for one synchronized frame set.

Pure functions on numpy arrays: no I/O, no bus. The matching engine
(`camnet.matching.engine`) detects with them, and matches a pair whole with
`match_pair` (`camnet.matching.reuse`).

Conventions: pixels ``(u, v)``, ``u`` to the right, ``v`` down, origin at the
centre of the top-left pixel (OpenCV's keypoint convention, so keypoints are
used as they come). Images are ``(H, W)`` grey or ``(H, W, 3)`` BGR, uint8.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from camnet.matching import nearest
from camnet.matching.images import (  # noqa: F401 (re-exported: the matcher's image functions)
    DARK_MEDIAN,
    LOW_CONTRAST_SPAN,
    few_features_reason,
    normalise_contrast,
    to_8bit,
    to_grey,
)

log = logging.getLogger(__name__)

class Detector(enum.StrEnum):
    SIFT = "sift"  # default: accurate, scale and rotation invariant
    ORB = "orb"  # fast option: binary descriptors, Hamming distance


@dataclass(frozen=True)
class MatcherConfig:
    """How features are detected and matched.

    Stereo prior: for the stereo pair (left, right), a candidate match must
    lie within `row_tolerance_px` of the same image row and have disparity
    ``u_left - u_right >= min_disparity_px``. Real pairs are only nearly
    parallel and distorted, so the band is generous; a small negative
    `min_disparity_px` lets distant points through when the principal points
    or a slight toe-in shift the zero of disparity.
    """

    detector: Detector = Detector.SIFT
    max_features: int = 4000
    ratio: float = 0.8  # Lowe's ratio: best distance < ratio * second best
    cross_check: bool = True  # keep only mutual nearest neighbours
    ransac_threshold_px: float = 1.0  # max distance to the epipolar line for an inlier
    ransac_confidence: float = 0.999
    ransac_max_iters: int = 10_000
    # A pair with fewer RANSAC inliers contributes nothing. An F fitted to a
    # handful of inliers among mostly false candidates is itself false, and
    # below about 20 inliers real and rendered pairs often have one
    # (docs/benchmarks.md, "Evidence behind the nodes' choices").
    min_matches: int = 20
    use_stereo_prior: bool = True
    row_tolerance_px: float = 40.0
    min_disparity_px: float = 0.0
    # The best in-band candidate may be at most this factor worse than the best
    # out-of-band one (1.1 tolerates repeated texture, rejects a missed partner).
    prior_outside_margin: float = 1.1
    max_image_side_px: int | None = None  # detect on a downscaled copy above this size
    # Real rigs run short exposures: dark or flat images are normal and SIFT's
    # contrast threshold loses most of their keypoints (docs/benchmarks.md, "The
    # matcher"). `normalise_contrast`: stretch, then CLAHE (see `normalise_contrast`).
    normalise_contrast: bool = True
    clahe_clip_limit: float = 2.0
    few_features: int = 200  # an image with fewer keypoints is reported, with the likely reason

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")
        if self.max_features <= 0:
            raise ValueError(f"max_features must be positive, got {self.max_features}")
        if self.ransac_threshold_px <= 0:
            raise ValueError(f"ransac_threshold_px must be > 0, got {self.ransac_threshold_px}")
        if self.min_matches < 8:
            raise ValueError(f"min_matches must be >= 8 (for F), got {self.min_matches}")
        if self.row_tolerance_px < 0:
            raise ValueError(f"row_tolerance_px must be >= 0, got {self.row_tolerance_px}")
        if not self.clahe_clip_limit > 0:
            raise ValueError(f"clahe_clip_limit must be > 0, got {self.clahe_clip_limit}")


@dataclass(frozen=True)
class Features:
    """Keypoints of one image: pixels (n, 2) float64 and descriptors (n, d)."""

    uv: np.ndarray  # (n, 2) pixels, camnet convention
    descriptors: np.ndarray  # (n, d) float32 (SIFT) or uint8 (ORB)
    detector: Detector
    shortage: str | None = None  # why the image gave fewer than MatcherConfig.few_features, and what to do

    def __len__(self) -> int:
        return len(self.uv)


@dataclass(frozen=True)
class PairMatches:
    """RANSAC-verified matches between cameras `a` and `b` (indices into the frame set)."""

    a: int
    b: int
    index_a: np.ndarray  # (m,) keypoint indices in image a
    index_b: np.ndarray  # (m,) keypoint indices in image b
    F: np.ndarray | None  # 3x3, x_b^T F x_a = 0 in pixels; None when too few matches
    candidates: int  # matches before RANSAC (after ratio, cross check and prior)

    def __len__(self) -> int:
        return len(self.index_a)


@dataclass(frozen=True)
class FrameSetMatches:
    """Features of every camera of one frame set and the verified matches of every pair."""

    camera_ids: tuple[str, ...]
    features: tuple[Features, ...]
    pairs: tuple[PairMatches, ...] = field(default_factory=tuple)


def _make_detector(config: MatcherConfig, max_features: int):
    if config.detector is Detector.SIFT:
        # Without precise upscaling, OpenCV's SIFT doubles the image with a
        # corner-origin convention and every keypoint lands 0.25 px right of
        # and below the true position (measured on Gaussian blobs).
        return cv2.SIFT_create(nfeatures=max_features, enable_precise_upscale=True)
    # FAST threshold lowered from 20 so that low-contrast scenes still yield features.
    return cv2.ORB_create(nfeatures=max_features, fastThreshold=10)


def detection_grey(image: np.ndarray, config: MatcherConfig = MatcherConfig()) -> tuple[np.ndarray, np.ndarray]:
    """(grey of the image's depth, uint8 grey to detect on): normalised (`config.normalise_contrast`) or
    reduced to 8 bits as it is."""
    raw = to_grey(image)
    grey = normalise_contrast(raw, clip_limit=config.clahe_clip_limit) if config.normalise_contrast else to_8bit(raw)
    return raw, grey


def detection_scale(shape: tuple[int, ...], config: MatcherConfig) -> float:
    """The factor s by which an image of `shape` is downscaled for detection (1: not at all)."""
    limit = config.max_image_side_px
    return max(shape[:2]) / limit if limit is not None and max(shape[:2]) > limit else 1.0


def detect_grey(grey: np.ndarray, config: MatcherConfig, *, scale: float = 1.0,
                max_features: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(uv (n, 2), descriptors or None) of uint8 `grey`, detected on a copy downscaled by `scale`,
    keypoints mapped back with ``u = (u_s + 0.5) * s - 0.5`` (origin at the centre of the top-left pixel)."""
    if scale != 1.0:
        size = (max(1, round(grey.shape[1] / scale)), max(1, round(grey.shape[0] / scale)))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    limit = config.max_features if max_features is None else max_features
    keypoints, descriptors = _make_detector(config, limit).detectAndCompute(grey, None)
    if descriptors is None or not keypoints:
        return np.empty((0, 2)), None
    uv = np.array([kp.pt for kp in keypoints], dtype=float).reshape(len(keypoints), 2)
    if scale != 1.0:
        uv = (uv + 0.5) * scale - 0.5
    # SIFT can return more than nfeatures when keypoints tie in response.
    return uv[:limit], descriptors[:limit]


def empty_descriptors(detector: Detector) -> np.ndarray:
    return np.empty((0, 128), np.float32) if detector is Detector.SIFT else np.empty((0, 32), np.uint8)


def detect(image: np.ndarray, config: MatcherConfig = MatcherConfig()) -> Features:
    """Detect keypoints and descriptors in one image (uint8 or uint16, grey or colour).

    With `config.normalise_contrast` the grey image is stretched and
    equalised first (`normalise_contrast`), else reduced to 8 bits as it is.
    Above `config.max_image_side_px` the image is downscaled by s for
    detection and the keypoints mapped back with ``u = (u_s + 0.5) * s - 0.5``,
    which keeps the origin at the centre of the top-left pixel. Fewer than
    `config.few_features` keypoints: `Features.shortage` says why.
    """
    raw, grey = detection_grey(image, config)
    uv, descriptors = detect_grey(grey, config, scale=detection_scale(grey.shape, config))
    shortage = few_features_reason(raw, len(uv)) if len(uv) < config.few_features else None
    if descriptors is None:
        return Features(uv, empty_descriptors(config.detector), config.detector, shortage)
    return Features(uv, descriptors, config.detector, shortage)


def stereo_candidate_mask(
    uv_left: np.ndarray, uv_right: np.ndarray, *, row_tolerance_px: float, min_disparity_px: float
) -> np.ndarray:
    """Boolean (n_left, n_right): pairs allowed by the near-parallel stereo prior.

    Allowed: ``|v_l - v_r| <= row_tolerance_px`` and
    ``u_l - u_r >= min_disparity_px`` (the right camera sits to the right).
    """
    dv = np.abs(uv_left[:, None, 1] - uv_right[None, :, 1])
    du = uv_left[:, None, 0] - uv_right[None, :, 0]
    return (dv <= row_tolerance_px) & (du >= min_disparity_px)


def mutual_ratio_matches(
    fa: Features,
    fb: Features,
    *,
    ratio: float,
    cross_check: bool,
    allowed=None,
    outside_margin: float = 1.1,
    operands: tuple[nearest.Operands, nearest.Operands] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matches a -> b passing Lowe's ratio test (and the cross check).

    `allowed(rows)` may return a boolean (len(rows), n_b) mask of candidate
    pairs; the ratio test and the cross check then run among allowed
    candidates only, so that a repeated texture outside the band does not
    veto a good match inside it. A geometric prior cannot reject a wrong
    match inside its own band, so the best allowed candidate must also be
    within `outside_margin` times the best disallowed one: when the true
    partner lies outside the band (the prior is wrong for this point), the
    in-band best is a random feature and is dropped. `operands`: `fa`'s and
    `fb`'s descriptors as `camnet.matching.nearest.operands` made them, where
    the caller keeps them for several pairs.
    Returns index arrays (m,) into `fa` and `fb`.
    """
    empty = np.empty(0, dtype=np.int64)
    if len(fa) < 2 or len(fb) < 2:
        return empty, empty
    if allowed is None and fa.detector is Detector.ORB and operands is None:
        return _bf_mutual_ratio(fa, fb, ratio=ratio, cross_check=cross_check)
    binary = fa.detector is Detector.ORB
    a, b = operands or (nearest.operands(fa.descriptors, binary=binary),
                        nearest.operands(fb.descriptors, binary=binary))
    # Distances of SIFT are squared: so are the factors they are compared with.
    power = 1 if binary else 2
    return nearest.mutual_ratio(a, b, ratio=ratio**power, cross_check=cross_check, allowed=allowed,
                                outside_margin=outside_margin**power)


def _bf_mutual_ratio(fa: Features, fb: Features, *, ratio: float, cross_check: bool) -> tuple[np.ndarray, np.ndarray]:
    """`mutual_ratio_matches` without a prior by OpenCV's brute force matcher.

    Same result as the dense path; for binary descriptors it is faster, as
    OpenCV counts bits directly instead of multiplying unpacked bits
    (docs/benchmarks.md, "Evidence behind the nodes' choices").
    """
    norm = cv2.NORM_HAMMING if fa.detector is Detector.ORB else cv2.NORM_L2
    matcher = cv2.BFMatcher(norm)
    knn = matcher.knnMatch(fa.descriptors, fb.descriptors, k=2)
    rows = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    if not rows:
        empty = np.empty(0, dtype=np.int64)
        return empty, empty
    ia, ib = (np.array(x, dtype=np.int64) for x in zip(*rows, strict=True))
    if cross_check:
        back = np.full(len(fb), -1, dtype=np.int64)
        for m in matcher.match(fb.descriptors, fa.descriptors):
            back[m.queryIdx] = m.trainIdx
        mutual = back[ib] == ia
        ia, ib = ia[mutual], ib[mutual]
    return ia, ib


def ransac_fundamental(
    uv_a: np.ndarray, uv_b: np.ndarray, config: MatcherConfig
) -> tuple[np.ndarray | None, np.ndarray]:
    """Fundamental matrix (x_b^T F x_a = 0, pixels) and inlier mask by USAC MAGSAC."""
    if len(uv_a) < config.min_matches:
        return None, np.zeros(len(uv_a), dtype=bool)
    F, mask = cv2.findFundamentalMat(
        uv_a.astype(np.float64),
        uv_b.astype(np.float64),
        cv2.USAC_MAGSAC,
        config.ransac_threshold_px,
        config.ransac_confidence,
        config.ransac_max_iters,
    )
    if F is None or mask is None or F.shape != (3, 3):
        # OpenCV returns None (or stacked solutions) when no model is found.
        return None, np.zeros(len(uv_a), dtype=bool)
    return F, mask.ravel().astype(bool)


def candidate_matches(fa: Features, fb: Features, config: MatcherConfig = MatcherConfig(), *,
                      stereo_prior: bool = False,
                      operands: tuple[nearest.Operands, nearest.Operands] | None = None,
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Indices (m,) into `fa` and `fb` passing the ratio test, the cross check and the optional stereo
    prior (a = left, b = right): the candidates RANSAC then verifies. `operands`: as for
    `mutual_ratio_matches`."""
    allowed = None
    if stereo_prior:

        def allowed(rows: np.ndarray) -> np.ndarray:
            return stereo_candidate_mask(
                fa.uv[rows],
                fb.uv,
                row_tolerance_px=config.row_tolerance_px,
                min_disparity_px=config.min_disparity_px,
            )

    return mutual_ratio_matches(
        fa,
        fb,
        ratio=config.ratio,
        cross_check=config.cross_check,
        allowed=allowed,
        outside_margin=config.prior_outside_margin,
        operands=operands,
    )


def match_pair(
    fa: Features,
    fb: Features,
    config: MatcherConfig = MatcherConfig(),
    *,
    stereo_prior: bool = False,
    a: int = 0,
    b: int = 1,
) -> PairMatches:
    """Ratio test, cross check, optional stereo prior (a = left, b = right), then RANSAC on F."""
    ia, ib = candidate_matches(fa, fb, config, stereo_prior=stereo_prior)
    F, inliers = ransac_fundamental(fa.uv[ia], fb.uv[ib], config)
    if F is None or inliers.sum() < config.min_matches:
        log.debug("pair %d-%d: %d candidates, too few RANSAC inliers", a, b, len(ia))
        empty = np.empty(0, dtype=np.int64)
        return PairMatches(a, b, empty, empty, None, len(ia))
    return PairMatches(a, b, ia[inliers], ib[inliers], F, len(ia))
