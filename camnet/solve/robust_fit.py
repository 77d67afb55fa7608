"""The robust side of a calibration: adjustments with a robust loss from a rough start, and
the outlier rejection that follows them (see camnet.solve.pipeline).

Residuals in pixels, predicted minus observed; the robust loss's scale is
``Options.loss_scale_px``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from camnet.model import rowwise
from camnet.solve import bundle
from camnet.solve.bundle import CentreMode, Problem, State
from camnet.solve.free_rule import free_mask
from camnet.solve.uncertainty import pixel_sigma

if TYPE_CHECKING:
    from camnet.solve.options import Options

# The median length of a 2-D residual with Gaussian noise of sigma per axis (Rayleigh):
# sqrt(2 ln 2) sigma. Dividing a median residual by it gives a sigma that outliers barely move.
MEDIAN_RESIDUAL_PER_SIGMA = 1.1774


def reject_outliers(problem: Problem, state: State, options: Options, *, residuals: np.ndarray | None = None
                    ) -> np.ndarray:
    """Observations to keep: residual within outlier_sigmas robust sigmas, tracks with >= 2 views.

    residuals (n, 2): `bundle.residuals` at `state`, pixels, where the caller has them.
    """
    r = rowwise.lengths(bundle.residuals(problem, state) if residuals is None else residuals)
    sigma = np.median(r) / MEDIAN_RESIDUAL_PER_SIGMA
    keep = r <= max(options.outlier_sigmas * sigma, options.min_outlier_px)
    views = np.bincount(problem.pt[keep], minlength=problem.n_points)
    return keep & (views[problem.pt] >= 2)


def inliers_and_sigma(full: Problem, state: State, options: Options, *, residuals: np.ndarray | None = None
                      ) -> tuple[np.ndarray, float]:
    """(inliers (n,), pixel sigma): `reject_outliers`, and the a-posteriori pixel sigma of the inliers
    (`uncertainty.pixel_sigma`) from the same residuals."""
    r = bundle.residuals(full, state) if residuals is None else residuals
    inliers = reject_outliers(full, state, options, residuals=r)
    return inliers, pixel_sigma(full.subset(inliers), state, residuals=r[inliers])


def robust_passes(full: Problem, state: State, options: Options, *, cold: bool, held_K, held_dist,
                   hold_pair: bool) -> State:
    """The robust adjustment of every parameter that moves, from a rough start.

    hold_pair: the stereo pair held as the ideal pair in the first pass. Of the
    known distances only the stereo pair's: the start knows no other, and held
    to one far from it a network tears; they enter the least squares that follows.
    """
    full = replace(full, distances=full.distances.between(0, 1))
    robust = dict(loss=options.loss, scale_px=options.loss_scale_px, max_iterations=options.max_iterations)
    if cold and options.free == "auto" and options.method == "refined":
        # Outliers are judged with the stereo pair free to turn: a pair that is not quite
        # parallel, or principal points off centre, must not cost it its observations.
        full = replace(full, rot_free=full.rot_free | (np.arange(full.n_cameras) == 1)[:, None])
    if cold and options.method != "unconstrained":
        # Continuation: a first pass moves focal lengths and the poses outside the
        # stereo pair only; freeing
        # principal points or distortion far from the solution lets the adjustment
        # settle in a wrong valley.
        M = full.n_cameras
        pair = (np.arange(M) == 1) & hold_pair
        first = replace(
            full,
            intr_free=full.intr_free & free_mask(M, frozenset({"f"}), held_K, held_dist),
            rot_free=full.rot_free & ~pair[:, None],
            centre_mode=np.where(pair, CentreMode.FIXED, full.centre_mode),
        )
        state, info = bundle.solve(first, state, **robust)
        if info.converged and _same_free(first, full):  # the second pass would repeat the first
            return state
    state, _ = bundle.solve(full, state, **robust)
    return state


def _same_free(a: Problem, b: Problem) -> bool:
    """Whether two problems move the same parameters."""
    return (np.array_equal(a.intr_free, b.intr_free) and np.array_equal(a.rot_free, b.rot_free)
            and np.array_equal(a.centre_mode, b.centre_mode))


def fit_points(full: Problem, state: State, which: np.ndarray, options: Options) -> State:
    """Robust fit of the points marked in `which` (N,) with every camera held."""
    rows = which[full.pt]
    if not rows.any():
        return state
    # Only these points and their observations: with the cameras held, the rest take no part.
    points = np.flatnonzero(which)
    points_only = replace(
        full.subset(rows),
        pt=np.searchsorted(points, full.pt[rows]),
        n_points=len(points),
        intr_free=np.zeros_like(full.intr_free),
        rot_free=np.zeros_like(full.rot_free),
        centre_mode=np.full_like(full.centre_mode, CentreMode.FIXED),
    )
    # A start for the joint adjustment, which refines these points again: loose tolerance.
    fitted, _ = bundle.solve(
        points_only,
        replace(state, X=state.X[points]),
        loss=options.loss,
        scale_px=options.loss_scale_px,
        max_iterations=options.max_iterations,
        ftol=1e-6,
    )
    X = state.X.copy()
    X[points] = fitted.X
    return replace(state, X=X)


def near_solution(problem: Problem, residuals: np.ndarray, options: Options) -> bool:
    """Whether every camera's median residual is within the outlier threshold (no camera moved).

    residuals (n, 2): `bundle.residuals` of `problem`, pixels.
    """
    r = rowwise.lengths(residuals)
    threshold = max(options.outlier_sigmas * np.median(r) / MEDIAN_RESIDUAL_PER_SIGMA, options.min_outlier_px)
    for m in range(problem.n_cameras):
        mine = r[problem.cam == m]
        if len(mine) and np.median(mine) > threshold:
            return False
    return True

