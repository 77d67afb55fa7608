"""The matcher node's options, and what of them the rig file sets."""

from __future__ import annotations

from dataclasses import dataclass

from camnet.errors import InputError
from camnet.io.rig import Rig
from camnet.matching.edge import EdgeConfig
from camnet.matching.engine import EngineConfig
from camnet.matching.features import Detector, MatcherConfig
from camnet.matching.pool import PoolConfig
from camnet.matching.viewgraph import ViewGraphConfig
from camnet.model.observations import Stereo


@dataclass(frozen=True)
class MatcherNodeConfig:
    """Options of the matcher node; see `camnet matcher --help` for their meaning."""

    detector: Detector = Detector.SIFT
    sync_tolerance_ms: float = 5.0  # capture times of one frame set differ by at most this
    max_wait_s: float = 0.5  # then a frame set goes without its late cameras (never without the stereo pair)
    # The cameras are not triggered together: a set takes each camera's frame nearest to the reference's,
    # within half that camera's frame period (camnet.bus.sync).
    sync_free_run: bool = False
    frames_per_camera: int = 4  # latest frames kept per camera while matching runs
    # At most one observations document per period; 0: after every frame set that changed the pool, so that
    # the calibrator, which always solves the latest document, never waits for a period to end.
    publish_period_s: float = 0.0
    max_tracks: int = 5000  # pool bound
    max_features: int = 4000  # per image
    max_image_side_px: int | None = None  # detect on a downscaled copy above this size
    # Once the pool holds max_tracks, a frame set's new tracks only replace others: then detect on a copy
    # downscaled to this size (if smaller than the above; None: never). A smaller copy saves CPU and costs
    # focal accuracy (640 px doubles the focal errors); on a quiet machine full size meets the latency target
    # with half the focal error of 960 px, so full size is the default; 960 is for a loaded host
    # (docs/benchmarks.md, "The live network"; "Evidence behind the nodes' choices").
    full_pool_image_side_px: int | None = None
    normalise_contrast: bool = True  # stretch and equalise each image before detection
    stats_period_s: float = 1.0
    lockstep: bool = False  # frames come from `camnet replay --lockstep`, one step at a time
    keyframe_period: int = 30  # frames detected here: whole at least every this many (1: always)
    view_graph: bool = True  # once calibrated, match only the pairs that overlap (and a few others)
    explore_pairs: int = 1  # with the view graph: other pairs matched per frame set, in rotation

    def __post_init__(self) -> None:
        if not isinstance(self.detector, Detector):
            raise InputError(f"detector: expected a Detector, got {self.detector!r}")
        for name in ("sync_tolerance_ms", "max_wait_s"):
            if not getattr(self, name) >= 0:
                raise InputError(f"{name}: must be >= 0, got {getattr(self, name)}")
        if not self.publish_period_s >= 0 or not self.stats_period_s > 0:
            raise InputError(f"publish_period_s, stats_period_s: must be >= 0 and > 0, got {self.publish_period_s}, "
                             f"{self.stats_period_s}")
        for name in ("frames_per_camera", "max_tracks", "max_features"):
            if getattr(self, name) < 1:
                raise InputError(f"{name}: must be at least 1, got {getattr(self, name)}")
        if self.keyframe_period < 1 or self.explore_pairs < 0:
            raise InputError(f"keyframe_period, explore_pairs: must be >= 1 and >= 0, got {self.keyframe_period}, "
                             f"{self.explore_pairs}")
        for name in ("max_image_side_px", "full_pool_image_side_px"):
            if getattr(self, name) is not None and getattr(self, name) < 16:
                raise InputError(f"{name}: must be at least 16, got {getattr(self, name)}")

    def engine_config(self) -> EngineConfig:
        """The matching engine's part of these options."""
        return EngineConfig(
            matcher=MatcherConfig(detector=self.detector, max_features=self.max_features,
                                  max_image_side_px=self.max_image_side_px, normalise_contrast=self.normalise_contrast),
            full_pool_image_side_px=self.full_pool_image_side_px, edge=EdgeConfig(keyframe_period=self.keyframe_period),
            view_graph=ViewGraphConfig(explore_per_set=self.explore_pairs), pool=PoolConfig(max_tracks=self.max_tracks))


def rig_stereo(rig: Rig) -> Stereo:
    """The rig's stereo pair; InputError if it has none."""
    if rig.stereo is None:
        raise InputError(f"{rig.source}: rig {rig.name!r} has no stereo pair; the matcher needs one "
                         "(add a 'stereo:' section with left, right and baseline_m)")
    return Stereo(rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m, sigma_m=rig.stereo.sigma_m,
                  parallel=rig.stereo.parallel)


def rig_options(rig: Rig) -> dict:
    """The MatcherNodeConfig fields the rig file sets (its `sync` section); the node's flags override them."""
    if rig.sync is None:
        return {}
    given = {"sync_tolerance_ms": rig.sync.tolerance_ms, "max_wait_s": rig.sync.max_wait_s,
             "sync_free_run": rig.sync.free_run}
    return {name: value for name, value in given.items() if value is not None}
