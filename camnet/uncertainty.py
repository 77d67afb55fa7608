"""Covariance of a bundle adjustment solution, and the Cramer-Rao bound.

At a least-squares solution the covariance of the parameters is
``sigma^2 (J^T J)^-1``. With the points eliminated, the camera block is
``sigma^2 S^-1`` (S the Schur complement) and any scalar function g of the
parameters has variance ``sigma^2 grad(g)^T H^-1 grad(g)``, evaluated here
without forming the dense inverse. With the true parameters and the true
noise sigma, the same quantities are the Cramer-Rao bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from camnet.bundle import NormalEquations, Problem, State, normal_equations, times_block_diag


@dataclass(frozen=True)
class Covariance:
    sigma_px: float  # pixel noise sigma the covariance is scaled by
    S_inv: np.ndarray  # (Pc, Pc) inverse Schur complement (unscaled)
    W: np.ndarray  # (Pc, 3N)
    V_inv: np.ndarray  # (N, 3, 3)
    columns: np.ndarray  # (M, 15) problem.columns()

    @property
    def cameras(self) -> np.ndarray:
        """(Pc, Pc) covariance of the camera parameters."""
        return self.sigma_px**2 * self.S_inv

    def variance(self, g_cam: np.ndarray | None, g_pts: np.ndarray | None) -> float:
        """Variance of a linear function with gradient (g_cam (Pc,), g_pts (N, 3))."""
        Pc, N = self.S_inv.shape[0], len(self.V_inv)
        gc = np.zeros(Pc) if g_cam is None else g_cam
        gp = np.zeros((N, 3)) if g_pts is None else g_pts
        # Solve H x = g by the Schur complement, then g^T x.
        y = np.einsum("nij,nj->ni", self.V_inv, gp)
        xc = self.S_inv @ (gc - self.W @ y.reshape(-1))
        xp = y - np.einsum("nij,nj->ni", self.V_inv, (self.W.T @ xc).reshape(-1, 3))
        return float(self.sigma_px**2 * (gc @ xc + np.sum(gp * xp)))

    def point_sigmas_m(self) -> np.ndarray:
        """(N,) RMS over axes of each point's standard deviation, metres."""
        WV = times_block_diag(self.W, self.V_inv)
        extra = np.sum((self.S_inv @ WV) * WV, axis=0).reshape(-1, 3).sum(axis=1)
        total = np.einsum("nii->n", self.V_inv) + extra
        return self.sigma_px * np.sqrt(np.maximum(total, 0.0) / 3.0)


def covariance(
    problem: Problem, state: State, *, sigma_px: float | None = None, normal: NormalEquations | None = None
) -> Covariance:
    """Covariance at `state`; sigma_px None estimates it from the residuals (a posteriori).

    normal: the unweighted normal equations at `state` when the caller has them.
    """
    ne = normal_equations(problem, state) if normal is None else normal
    # A point left without observations (all rejected), or seen along one ray only,
    # carries no information in some directions: the pseudo-inverse gives it none.
    V_inv = np.linalg.pinv(ne.V, hermitian=True)
    S = ne.U - times_block_diag(ne.W, V_inv) @ ne.W.T
    S_inv = scipy.linalg.pinvh(S) if len(S) else S
    if sigma_px is None:
        cols, n_cols = problem.columns()
        dof = 2 * len(problem.cam) - n_cols - 3 * problem.n_points
        sigma_px = float(np.sqrt(2.0 * ne.cost / max(dof, 1)))
    return Covariance(sigma_px, S_inv, ne.W, V_inv, problem.columns()[0])


def scale_gradient(points: np.ndarray) -> np.ndarray:
    """Gradient of the similarity scale of a point cloud with respect to its points.

    The least-squares similarity that maps the true cloud onto the estimate
    has, to first order, the scale ``1 + sum(c_j . e_j) / sum(|c_j|^2)``
    (c_j the centred true points, e_j the errors); rotation and translation
    errors do not enter it.
    """
    c = points - points.mean(axis=0)
    return c / np.sum(c * c)


FAR_FACTOR = 5.0


def scale_sigma(cov: Covariance, points: np.ndarray, kept: np.ndarray | None = None) -> float:
    """Standard deviation of the network's scale (relative, 0.001 = 0.1%).

    kept: the points that make up the cloud (default all); rejected tracks
    are left out of it. So are points more than `FAR_FACTOR` times the median
    distance from the cloud's median: tracks with almost no parallax land far
    away with huge variances, and through their lever arm they would swamp
    the scale of the cloud's body, which is what the scale is about.
    """
    kept = np.ones(len(points), dtype=bool) if kept is None else kept.copy()
    if kept.any():
        distance = np.linalg.norm(points - np.median(points[kept], axis=0), axis=1)
        kept &= distance <= FAR_FACTOR * np.median(distance[kept])
    g = np.zeros_like(points)
    g[kept] = scale_gradient(points[kept])
    return float(np.sqrt(cov.variance(None, g)))


def shape_rms_bound_m(cov: Covariance, points: np.ndarray) -> float:
    """Expected RMS point error (m) after similarity alignment, ``sqrt(tr(P Sigma P) / N)``.

    P removes the 7 similarity directions (translation, rotation, scale).
    """
    N = len(points)
    c = points - points.mean(axis=0)
    basis = []
    for k in range(3):
        e = np.zeros((N, 3))
        e[:, k] = 1.0
        basis.append(e)
        w = np.zeros(3)
        w[k] = 1.0
        basis.append(np.cross(w, c))
    basis.append(c)
    Q, _ = np.linalg.qr(np.stack([b.reshape(-1) for b in basis], axis=1))
    WV = times_block_diag(cov.W, cov.V_inv)
    trace_total = float(np.einsum("nii->", cov.V_inv)) + float(np.sum(cov.S_inv * (WV @ WV.T)))
    VQ = np.einsum("nij,njk->nik", cov.V_inv, Q.reshape(N, 3, -1)).reshape(3 * N, -1)
    WVQ = WV @ Q
    trace_sim = float(np.trace(Q.T @ VQ) + np.trace(WVQ.T @ cov.S_inv @ WVQ))
    return cov.sigma_px * float(np.sqrt(max(trace_total - trace_sim, 0.0) / N))
