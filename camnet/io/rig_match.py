"""Whether observations or a calibration belong to a rig: its cameras, their image sizes, its baseline.

Any peer may publish on a rig's keys, and a state file may come from another
rig: what does not match the rig file would become a calibration of the
wrong rig (forged observations of another rig with a 0.5 m baseline became
calibrations; a state file of another rig was served). Each check returns
None when `rig` agrees, else one line saying what differs.
"""

from __future__ import annotations

import numpy as np

from camnet.io.rig import Rig, configured_size
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations

# A solved calibration keeps an exact baseline exactly; a soft one (sigma_m) moves within its sigmas.
BASELINE_TOLERANCE_REL = 1e-6
SOLVED_BASELINE_SIGMAS = 5.0


def _cameras_mismatch(rig: Rig, cameras: list[tuple[str, int, int]]) -> str | None:
    ids = {c.id for c in rig.cameras}
    for camera_id, width, height in cameras:
        if camera_id not in ids:
            return f"camera {camera_id!r} is not in rig {rig.name!r} (cameras: {', '.join(sorted(ids))})"
        size = configured_size(rig, camera_id)
        if size is not None and size != (width, height):
            return f"camera {camera_id!r} is {width}x{height}, the rig file says {size[0]}x{size[1]}"
    return None


def observations_mismatch(rig: Rig, obs: Observations) -> str | None:
    """What in `obs` is not of `rig` (camera ids, image sizes, the stereo pair and its baseline), or None."""
    found = _cameras_mismatch(rig, [(c.id, c.width, c.height) for c in obs.cameras])
    if found is not None or rig.stereo is None:
        return found
    want, got = rig.stereo, obs.stereo
    if (got.left, got.right) != (want.left, want.right):
        return f"stereo pair {got.left}-{got.right}, the rig's is {want.left}-{want.right}"
    if not np.isclose(got.baseline_m, want.baseline_m, rtol=BASELINE_TOLERANCE_REL, atol=0.0):
        return f"stereo baseline {got.baseline_m:g} m, the rig's is {want.baseline_m:g} m"
    return None


def calibration_mismatch(rig: Rig, cal: Calibration) -> str | None:
    """What in `cal` is not of `rig` (camera ids, image sizes, the stereo cameras' distance), or None."""
    found = _cameras_mismatch(rig, [(c.id, c.width, c.height) for c in cal.cameras])
    if found is not None or rig.stereo is None:
        return found
    by_id = {c.id: c for c in cal.cameras}
    want = rig.stereo
    if want.left not in by_id or want.right not in by_id:
        return f"it lacks the stereo pair {want.left}-{want.right}"
    distance_m = float(np.linalg.norm(by_id[want.left].centre - by_id[want.right].centre))
    tolerance_m = want.baseline_m * BASELINE_TOLERANCE_REL + SOLVED_BASELINE_SIGMAS * want.sigma_m
    if abs(distance_m - want.baseline_m) > max(tolerance_m, 1e-4 * want.baseline_m):
        return f"its stereo cameras are {distance_m:g} m apart, the rig's baseline is {want.baseline_m:g} m"
    return None
