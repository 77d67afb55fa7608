"""The automatic free rule on lenses unlike the paper's: it finds strong distortion by itself."""

import numpy as np
import pytest

from camnet.geometry.calibrate import calibrate
from camnet.geometry.evaluate import compare
from camnet.sim.families import WIDE_DIST, family
from camnet.sim.simulate import observe


# Seeds 2, 3, 8: one camera's k2 alone is not significant until the others' is freed.
@pytest.mark.parametrize("seed", [0, 2, 3, 8])
def test_100_degree_lenses_calibrate_at_default_options(seed):
    drawn = family("wide", seed=seed)
    obs = observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations
    cal = calibrate(obs).calibration
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    assert c.rms_reprojection_px < 0.6  # the noise is 0.5 px: no lens error is left
    assert abs(c.scale_rel) < 1e-2 and abs(c.scale_rel) < 3 * c.scale_sigma_rel
    for e in c.cameras:
        assert abs(e.focal_rel) < 3 * e.focal_sigma_rel
    for cam in cal.cameras:
        np.testing.assert_allclose(cam.dist[:2], WIDE_DIST, atol=0.01)
