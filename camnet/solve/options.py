"""The options of a solve (camnet.solve.pipeline): its method, robust loss, free set, outlier rule and priors."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from camnet.model.methods import Loss, Method


class World(StrEnum):
    """The frame a calibration is written in (the rig file's `world`)."""

    LEFT_CAMERA = "left_camera"  # the left stereo camera's, as the paper's
    FLOOR = "floor"  # found from the scene: floor, up and origin (camnet.solve.world_frame)


@dataclass(frozen=True)
class Options:
    method: Method = Method.REFINED
    loss: Loss = Loss.CAUCHY  # robust loss of the first adjustment
    loss_scale_px: float = 2.0
    free: str | frozenset[str] = "auto"  # "auto" or a subset of free_rule.FREE_NAMES
    determined_px: float = 1.0
    significance: float = 1e-3  # false-alarm rate of the auto rule's chi-square test
    outlier_sigmas: float = 4.0  # reject residuals beyond this many robust sigmas
    min_outlier_px: float = 1.5  # never reject residuals below this
    max_iterations: int = 300  # LM stops on the Gauss-Newton decrement long before this in most solves
    # 1 sigma of a guessed principal point about the image centre, as a fraction of the image size,
    # in the reported uncertainty (see uncertainty.covariance_with_pp_prior); 0 reports sigmas conditional on the guess.
    pp_prior_rel: float = 0.01
    # 1 sigma, degrees, of each rotation axis of the stereo pair that the solve holds, in the reported
    # uncertainty (uncertainty.held_at_tolerance); 0 reports sigmas conditional on the pair's held rotation.
    # None: free_rule.PAIR_TOLERANCE_DEG (it says why), or 0 from a start no solve made (a pose given as known).
    pair_tolerance_deg: float | None = None
    seed: int = 0
    # Solve the scene's two halves apart and widen the sigmas of what they disagree on (camnet.solve.halves):
    # the second opinion that the curvature at one minimum cannot give.
    halves: bool = True
    # Under the automatic rule, a warm start also tries to free what its start held: a pool that has grown since
    # may determine a lens the first few tracks could not (a webcam's k1), which held at zero biases its focal
    # length and distance together by more than their sigmas.
    free_again: bool = False
    world: World = World.LEFT_CAMERA

    def truncation_px(self, rms_px: float) -> float:
        """The MSAC cost's truncation for a solution of reprojection RMS `rms_px` (pixels): `outlier_sigmas` times
        it, at least `min_outlier_px`, as the outlier rejection's."""
        return max(self.min_outlier_px, self.outlier_sigmas * rms_px)
