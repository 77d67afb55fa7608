"""Images as the detector wants them: grey, 8 bits, contrast normalised; and why one gave few features."""

from __future__ import annotations

import cv2
import numpy as np

# ROS Bayer names -> OpenCV codes. OpenCV names a mosaic by the second row's
# second and third pixels, so ROS rggb is OpenCV's BG (the mapping cv_bridge uses).
_BAYER_TO_GREY = {
    "bayer_rggb8": cv2.COLOR_BayerBG2GRAY,
    "bayer_bggr8": cv2.COLOR_BayerRG2GRAY,
    "bayer_gbrg8": cv2.COLOR_BayerGR2GRAY,
    "bayer_grbg8": cv2.COLOR_BayerGB2GRAY,
}


def to_grey(image: np.ndarray, *, encoding: str | None = None) -> np.ndarray:
    """Grey image (H, W) of the image's depth (uint8 or uint16) from grey (H, W), (H, W, 1), BGR (H, W, 3) or BGRA.

    `encoding` (a camnet.bus.frame encoding name) says what a frame's pixels are:
    rgb8 is taken as RGB, bayer_* mosaics are demosaiced; without it three
    channels are BGR. uint16 (mono16) stays uint16: `detect` decides how its
    bits become 8 (`normalise_contrast` or `to_8bit`).
    """
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"expected a uint8 or uint16 image, got {image.dtype}")
    if encoding in _BAYER_TO_GREY and image.ndim == 2:
        return cv2.cvtColor(image, _BAYER_TO_GREY[encoding])
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY if encoding == "rgb8" else cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    raise ValueError(f"expected an (H, W) or (H, W, 1|3|4) image, got shape {image.shape}")


def to_8bit(grey: np.ndarray) -> np.ndarray:
    """uint8 from uint8 or uint16 grey: uint16 is shifted down keeping its highest used bit,
    so 10- or 12-bit data in 16-bit words keeps its contrast."""
    if grey.dtype == np.uint8:
        return grey
    shift = max(0, int(grey.max()).bit_length() - 8)
    return (grey >> shift).astype(np.uint8)


def normalise_contrast(grey: np.ndarray, *, clip_limit: float = 2.0) -> np.ndarray:
    """uint8 grey for detection from uint8 or uint16 grey of any brightness and contrast.

    First the 0.5 and 99.5 percentiles are stretched linearly to 0 and 255, at
    the image's own depth, so a 12-bit dark image keeps its shadow levels; then
    OpenCV's CLAHE (8 x 8 tiles, `clip_limit`) evens the contrast out locally.
    Either step alone falls short on a dark real image (median grey 25 of
    255), where both together give SIFT about the keypoints of the image as
    exposed (docs/benchmarks.md, "The matcher"). The mapping is monotonic within a tile and
    interpolated smoothly across tiles, so keypoints stay where they are.
    """
    low, high = np.percentile(grey, [0.5, 99.5])
    gain = 255.0 / max(float(high - low), 1.0)
    stretched = cv2.convertScaleAbs(grey, alpha=gain, beta=-low * gain)
    return cv2.createCLAHE(clipLimit=clip_limit, tileGridSize=(8, 8)).apply(stretched)


# What makes an image yield few keypoints, judged on its grey levels scaled to 0-255.
DARK_MEDIAN = 30.0
LOW_CONTRAST_SPAN = 40.0  # 99th minus 1st percentile


def few_features_reason(grey: np.ndarray, n_features: int) -> str:
    """Why a grey image (uint8 or uint16) gave only `n_features` keypoints, and what to do, in one phrase.

    Darkness is judged before contrast, as a dark image is also a narrow one.
    Blur and a textureless view are not told apart: no sharpness measure
    tried separated them from sensor noise and quantisation on real images.
    """
    full = 255.0 if grey.dtype == np.uint8 else 65535.0
    p1, median, p99 = np.percentile(grey, [1, 50, 99]) * (255.0 / full)
    if median < DARK_MEDIAN:
        return (f"{n_features} features: dark (median grey {median * full / 255:.0f} of {full:.0f}); "
                "raise the exposure or gain, or light the scene")
    if p99 - p1 < LOW_CONTRAST_SPAN:
        return (f"{n_features} features: low contrast (1-99% of grey levels span {p99 - p1:.0f} of 255); "
                "light the scene, clean the lens, or avoid glare")
    return (f"{n_features} features in a bright, contrasted image: blurred or uniform; focus the lens, "
            "shorten the exposure if the scene moves, or aim the camera at a textured part of the scene")
