"""What the scale's reported sigma rests on: the scene, the guessed principal points, the stereo pair held parallel.

The reported sigma counts two assumptions as uncertain: principal points
nobody gave (at the image centres, to `pp_prior_rel`) and the rotation
axes of a stereo pair held parallel (to the pair's tolerance). Each has its
figure, the sigma with only that cause removed (Uncertainty's
`scale_rel_if_pp_exact`, `scale_rel_if_pair_exact`), and both together
leave what the scene alone fixes (`scale_rel_if_pp_and_pair_exact`). The
two overlap (the right camera's horizontal principal point is its yaw to
first order), so removing either alone may leave most of the variance
while removing both leaves little (docs/benchmarks.md, "Rigs unlike the
paper's": the four figures on `ring` and `ring_K`).

The scene is the cause where what it alone leaves is at least half the
sigma (a quarter of the variance); else the assumptions are, and each is
named whose removal alone takes at least half of what they add, both where
neither does. With one assumption this is the rule the verdict had for the
principal points alone: the scene's where their figure is at least half
the sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

from camnet.model.calibration import Calibration, Uncertainty

# What to do where the scale rests on the pair held parallel (the verdict's, the warnings'): its rotation
# where a factory calibration gives it (the rig file; the observations' contract has no pair pose), or a
# tolerance the head is known to meet.
GIVE_PAIR_ROTATION = ("give the pair's rotation if it is known (its factory calibration's R and t as the rig "
                      "file's stereo.R and stereo.t), or its tolerance if it is known to be that parallel "
                      "(stereo.tolerance_deg in the rig file, --pair-tolerance-deg)")
# What to do where it rests on the pair held at a rotation it was given (`held_at_given_pose`): the rotation is
# there already; what the report cannot know is how well it holds.
TIGHTEN_PAIR_TOLERANCE = ("give a tighter tolerance if the given rotation is known better (stereo.tolerance_deg in "
                          "the rig file, --pair-tolerance-deg)")
FREE_PAIR_ROTATION = "free its rotation (--free stereo_rotation)"
GIVE_STEREO_K = "give the stereo cameras' K"
# The warning of a scale that rests on the pair's yaw held parallel (free_rule.held_yaw_warning) is given where
# the reported sigma is more than this many times the sigma were the held rotation exact: the tolerance takes
# three quarters of the variance or more, so the pair is always named then. Where it is named with less, the
# scale's message in the report's warnings says so instead; one message either way.
HELD_YAW_SHARE = 2.0


@dataclass(frozen=True)
class ScaleCause:
    """The causes named for the scale's sigma, with the figures that named them (relative 1 sigma).

    pp, pair: the guessed principal points, the pair's rotation held at its tolerance (neither: the scene);
    sigma: the reported one; if_pp, if_pair, if_both: with that cause removed (None where it is absent).
    """

    pp: bool
    pair: bool
    sigma: float
    if_pp: float | None
    if_pair: float | None
    if_both: float | None

    @property
    def scene(self) -> bool:
        return not (self.pp or self.pair)

    @property
    def if_named_exact(self) -> float:
        """The sigma were the named causes exact (the reported one where the scene is the cause)."""
        if self.pp and self.pair:
            return self.if_both
        return self.if_pp if self.pp else self.if_pair if self.pair else self.sigma


def scale_cause(u: Uncertainty) -> ScaleCause | None:
    """What the scale's sigma rests on (the module docstring's rule); None where it has no sigma."""
    sigma = u.scale_rel.value
    if sigma is None:
        return None
    if_pp, if_pair = u.scale_rel_if_pp_exact.value, u.scale_rel_if_pair_exact.value
    if_both = u.scale_rel_if_pp_and_pair_exact.value
    scene = min(x for x in (if_both, if_pp, if_pair, sigma) if x is not None)
    if scene >= sigma / 2:
        return ScaleCause(False, False, sigma, if_pp, if_pair, if_both)
    added = sigma**2 - scene**2  # what the assumptions add to the variance

    def takes_half(without: float | None) -> bool:
        return without is not None and sigma**2 - without**2 >= added / 2

    pp, pair = takes_half(if_pp), takes_half(if_pair)
    if not (pp or pair):  # neither alone: their overlap
        pp, pair = True, True
    return ScaleCause(pp, pair, sigma, if_pp, if_pair, if_both)


def held_at_given_pose(initial: Calibration | None) -> bool:
    """Whether a solve from `initial` holds the stereo pair's rotation at a given pose, not the ideal parallel pair.

    A solve holds the pair's held rotation axes where its start put them: a
    cold start at the parallel pair, a warm one at `initial`'s rotation. That
    rotation was given where no solve made `initial` (a factory head's R, t,
    which the live calibrator starts from), where the solve that made it held
    such a pose (its report's `pair_pose_given`), or where that solve
    estimated the yaw, which a solve that holds it keeps.
    """
    if initial is None:
        return False
    report = initial.report
    return report is None or report.pair_pose_given or (
        report.free is not None and "y" in report.free.stereo_rotation_axes)


def pair_rotation_todo(given: bool) -> str:
    """What to do where the scale rests on the pair's held rotation: give it, or, given, say how well it holds."""
    return f"{TIGHTEN_PAIR_TOLERANCE}, or {FREE_PAIR_ROTATION}" if given else GIVE_PAIR_ROTATION
