"""Each camera's solved pose checked against the relative poses its own two views with its neighbours give
(camnet.model.pair_pose_check): the camera that disagrees with most of them is named in a warning and in the
verdict (camnet.solve.report.pair_poses)."""

from __future__ import annotations

import time
from dataclasses import replace

from camnet.model.calibration import Calibration, PairPoseCheck
from camnet.model.observations import Observations
from camnet.model.pair_pose_check import pair_checks
from camnet.solve.report.pair_poses import pair_warnings


def with_pair_check(obs: Observations, cal: Calibration) -> Calibration:
    """`cal` with its cameras' pair checks against `obs` in its report, and a warning for each disagreement;
    the stereo pair is not checked where a rotation axis of it was held."""
    if cal.report is None:
        return cal
    t0 = time.perf_counter()
    free = cal.report.free
    held = free is not None and len(free.stereo_rotation_axes) < 3
    # A stereo pair held at a rotation has it as an assumption, priced by its tolerance, not as an estimate.
    skip = frozenset({frozenset((obs.stereo.left, obs.stereo.right))}) if held else frozenset()
    checks = tuple(pair_checks(cal, obs, skip=skip))
    report = replace(cal.report, timings_s={**cal.report.timings_s, "pair_check": time.perf_counter() - t0})
    return with_pairs_carried(replace(cal, report=report), checks)


def with_pairs_carried(cal: Calibration, checks: tuple[PairPoseCheck, ...]) -> Calibration:
    """`cal` with pair `checks` made of it or of an earlier solve of the same rig (the live calibrator checks
    only when it asks for a second opinion)."""
    report = cal.report
    if report is None:
        return cal
    warnings = report.warnings + tuple(pair_warnings(checks))
    return replace(cal, report=replace(report, pair_checks=checks, warnings=warnings))
