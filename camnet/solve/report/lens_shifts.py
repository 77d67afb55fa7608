"""What the lens check found (camnet.solve.lens_check), judged: the focal lengths that a lens held straight biased."""

from __future__ import annotations

from collections.abc import Mapping

from camnet.model.calibration import LensShift

SHIFT_SIGMAS = 3.0  # a focal length that moves this many of its sigmas with its lens free was biased held straight


def biased(shifts: Mapping[str, LensShift] | None) -> dict[str, LensShift]:
    """The cameras of `shifts` whose focal length moved beyond SHIFT_SIGMAS with their lens free."""
    return {c: s for c, s in sorted((shifts or {}).items()) if s.in_sigmas > SHIFT_SIGMAS}


def describe(shift: LensShift) -> str:
    """The move in words: "focal length moves by +7.8% (5.4 sigma) with its lens distortion free (k1 +0.105)"."""
    return (f"focal length moves by {100 * shift.f_rel:+.1f}% ({shift.in_sigmas:.1f} sigma) with its lens "
            f"distortion free (k1 {shift.k1:+.3f})")


def lens_warnings(shifts: Mapping[str, LensShift] | None) -> list[str]:
    """A warning for each biased focal length."""
    return [f"camera {c}'s {describe(s)}: held straight, as nobody gave its dist, its lens biases it"
            for c, s in biased(shifts).items()]
