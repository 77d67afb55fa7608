"""One solve judged by a policy's check, solved again without the cameras the check finds placed wrong.

A camera placed wrong (its tracks fit a wrong pose, or are false) need not
hold the others back: where the check passes the rig as a whole and refuses
the solve only for such cameras, the rest is solved again without them and
they are named in the report, each with the check's reason. The live
calibrator (camnet.live.tracker) and `camnet calibrate` solve so, with the
live policy's check (camnet.live.policy).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum

from camnet.errors import CamnetError, in_words
from camnet.live.moved_cameras import without_cameras
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.solve import Options, calibrate, with_second_opinion
from camnet.solve.start.cold import MIN_CAMERAS, with_cameras_left_out

REFUSED_RETRIES = 2  # a solve refused for cameras placed wrong is solved again without them at most this often


class Status(StrEnum):
    """What became of one solve."""

    GOOD = "good"  # the check passed it
    REJECTED = "rejected"  # it solved, but the check refused it
    FAILED = "failed"  # it did not solve


@dataclass(frozen=True)
class Refusal:
    """A check's answer: why a calibration must not stand ("" where it may) and, where the rig as a
    whole passes and only some cameras (never the stereo pair) refuse it, those cameras, each with why."""

    reason: str = ""
    placed_wrong: Mapping[str, str] = field(default_factory=dict)


Check = Callable[[Calibration, Observations], Refusal]


@dataclass(frozen=True)
class Judged:
    """One judged solve: `calibration` is None where it did not solve; `reason` is "" where it is good."""

    status: Status
    reason: str
    calibration: Calibration | None = None


def solve_judged(obs: Observations, start: Calibration | None, *, options: Options, check: Check,
                 reset: Collection[str] = (), retries: int = REFUSED_RETRIES,
                 leave_out: Mapping[str, str] | None = None) -> Judged:
    """`obs` solved from `start` (None: cold) and judged by `check`; where only cameras placed wrong refuse
    it, solved again without them (named in the report with the check's reason), up to `retries` times.

    reset: cameras of `start` whose pose is solved afresh (moved). leave_out: cameras solved without from
    the start, each with why (named in the report so). Never fewer than `cold_start.MIN_CAMERAS` cameras
    are left: a solve that would be is refused as it stands, as is one whose solve without those cameras
    fails.
    """
    left_out: dict[str, str] = dict(leave_out or {})
    if left_out:
        obs = without_cameras(obs, left_out)
    # The second opinion is asked once, of the solve kept, not of each attempt.
    second, options = options.halves, replace(options, halves=False)
    judged, refusal = _attempt(obs, start, options=options, check=check, reset=reset, left_out=dict(left_out))
    for _ in range(retries):
        refused = refusal.placed_wrong if judged.status == Status.REJECTED else {}
        if not refused or len(obs.cameras) - len(refused) < MIN_CAMERAS:
            break
        left_out.update(refused)
        fewer = without_cameras(obs, refused)
        again, refusal = _attempt(fewer, start, options=options, check=check, reset=reset, left_out=left_out)
        if again.status == Status.FAILED:
            # The refused solve is the last one that solved: a caller may still show it, with why not.
            judged = replace(judged, reason=f"{judged.reason}; without {in_words(sorted(refused))}: {again.reason}")
            break
        judged, obs = again, fewer
    if second and judged.calibration is not None:
        judged = replace(judged, calibration=with_second_opinion(obs, judged.calibration, options))
    return judged


def _attempt(obs: Observations, start: Calibration | None, *, options: Options, check: Check,
             reset: Collection[str], left_out: dict[str, str]) -> tuple[Judged, Refusal]:
    """One solve of `obs` from `start`, judged; `left_out`: cameras not in `obs`, and why."""
    try:
        reset = set(reset) & set(obs.camera_ids) if start is not None else ()
        result = calibrate(obs, options, initial=start, reset_cameras=reset)
    except CamnetError as exc:
        return Judged(Status.FAILED, f"solve failed: {exc}"), Refusal()
    if not result.converged:
        return Judged(Status.FAILED, f"solve failed: the adjustment did not converge: {result.reason}"), Refusal()
    cal = result.calibration
    if left_out:
        cal = replace(cal, report=with_cameras_left_out(cal.report, left_out))
    refusal = check(cal, obs)
    status = Status.REJECTED if refusal.reason else Status.GOOD
    return Judged(status, refusal.reason, cal), refusal
