"""Known distances between camera centres as residual rows of the bundle adjustment.

A second stereo head, a taped distance, or a soft stereo baseline each give
one row ``w (|C_a - C_b| - d)``. The pixel residuals have unit weight and
noise sigma_px, and the covariance is scaled by the sigma_px estimated from
them; a distance known to sigma_m, weighted by ``w = sigma_px / sigma_m``
(pixels per metre), then carries the information ``1 / sigma_m^2`` it
should, both in the solution and in its covariance.

Centres in metres, in the world frame (the left stereo camera's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.observations import Observations

# An exact distance (sigma_m 0) is held by a row this stiff rather than by a parametrisation:
# tying one camera's centre to another's would couple their blocks of the normal equations,
# which are block diagonal in the cameras. 1 micrometre is a thousandth of what a factory
# calibration or a tape knows, and far below what the pixels fix a centre to (0.1-1 mm), so the
# reported sigmas do not depend on it, while a much stiffer row leaves the normal equations too
# ill-conditioned for the adjustment to converge (docs/benchmarks.md, "Evidence behind the
# solver's thresholds").
EXACT_SIGMA_M = 1e-6
# Pixels fitted to rounding (a simulation without noise) would give the distances no weight at all.
MIN_SIGMA_PX = 0.01


@dataclass(frozen=True)
class Distances:
    """Distances between pairs of camera centres.

    cams (B, 2): problem camera indices; metres (B,): the distances;
    sigma_m (B,): their 1 sigma, metres, 0 for an exact one.
    """

    cams: np.ndarray
    metres: np.ndarray
    sigma_m: np.ndarray

    @staticmethod
    def none() -> Distances:
        return Distances(np.zeros((0, 2), dtype=int), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.metres)

    def between(self, a: int, b: int) -> Distances:
        """The distances between cameras a and b alone."""
        rows = np.all(np.sort(self.cams, axis=1) == sorted((a, b)), axis=1)
        return Distances(self.cams[rows], self.metres[rows], self.sigma_m[rows])

    def weights_px_per_m(self, sigma_px: float) -> np.ndarray:
        """(B,) the rows' weights: pixel sigma over distance sigma (EXACT_SIGMA_M for an exact one)."""
        return max(sigma_px, MIN_SIGMA_PX) / np.maximum(self.sigma_m, EXACT_SIGMA_M)

    def errors_m(self, C: np.ndarray) -> np.ndarray:
        """(B,) the distances between the centres C (M, 3) minus the known ones, metres."""
        return np.linalg.norm(C[self.cams[:, 0]] - C[self.cams[:, 1]], axis=1) - self.metres

    def directions(self, C: np.ndarray) -> np.ndarray:
        """(B, 3) unit vectors from C_b to C_a: the gradient of |C_a - C_b| in C_a (minus it in C_b)."""
        d = C[self.cams[:, 0]] - C[self.cams[:, 1]]
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)


def known_distances(obs: Observations, order: list[int]) -> Distances:
    """The distances `obs` knows beyond an exact stereo baseline, in problem camera order.

    order: problem camera m is observations camera order[m]. A soft stereo
    baseline is one of them; an exact one the adjustment holds by its gauge.
    """
    m_of = {obs.cameras[i].id: m for m, i in enumerate(order)}
    known = [(b.a, b.b, b.baseline_m, b.sigma_m) for b in obs.baselines]
    if obs.stereo.sigma_m > 0:
        known.insert(0, (obs.stereo.left, obs.stereo.right, obs.stereo.baseline_m, obs.stereo.sigma_m))
    if not known:
        return Distances.none()
    a, b, metres, sigma_m = zip(*known, strict=True)
    return Distances(np.array([[m_of[x] for x in a], [m_of[x] for x in b]]).T, np.array(metres), np.array(sigma_m))
