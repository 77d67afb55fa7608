"""Residuals with structure name the camera and the likely cause; clean solves raise no such warning."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.sim.families import family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate


def structure(warnings) -> list[str]:
    return [w for w in warnings if "grow with the distance" in w or "for the others" in w]


@pytest.mark.parametrize("seed", [0, 2])
def test_distortion_held_on_a_wide_lens_is_named(seed):
    drawn = family("wide", seed=seed)
    obs = observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations
    held = calibrate(obs, Options(free=frozenset({"f"}))).calibration.warnings
    # Every lens is a 100 degree one; which cameras show it most depends on where the solve settles.
    assert any("its residuals grow with the distance" in w and "lens distortion the solve held" in w for w in held)
    assert not structure(calibrate(obs).calibration.warnings)  # the default rule frees it: nothing left


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_camera_far_noisier_than_the_others_is_named(seed):
    obs = observe(make_rig(seed=seed), noise_px=0.5, seed=seed).observations
    assert not structure(calibrate(obs).calibration.warnings)
    mine = obs.cam_index == obs.index_of("mono_b")
    uv = obs.uv.copy()
    uv[mine] += np.random.default_rng(seed).normal(scale=2.0, size=(int(mine.sum()), 2))
    named = structure(calibrate(replace(obs, uv=uv)).calibration.warnings)
    assert len(named) == 1 and named[0].startswith("camera mono_b:")
