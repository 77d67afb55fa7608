"""Real scenes through `camnet match` and `camnet calibrate`, as a new user runs them, against their references:
right within 3 reported sigma, or refused, or rated poor. Never "good" or "usable" and wrong.

The scenes where camnet was once wrong in silence: the fountain (a
verdict of good with focal lengths and rotations 5-25 sigma off) and the
courtyard (a 5 m pair 40 m from its scene, with the pair's K: a verdict
of good 2.8% off in scale at a sigma of 0.15%). benchmarks/bench_real.py
runs every scene and frame set; these are the ones CI can afford.
"""

from __future__ import annotations

import pytest

from camnet.datasets.sigma_check import Outcome
from tests._bench_real import load_bench
from tests._groundtruth import CASTLE_ROOT, STRECHA_ROOT, require

HONEST = (Outcome.RIGHT, Outcome.REFUSED, Outcome.POOR_AND_WRONG)



@pytest.mark.parametrize(("root", "known"), [(STRECHA_ROOT, "none"), (STRECHA_ROOT, "K"), (CASTLE_ROOT, "K")],
                         ids=["fountain-none", "fountain-K", "castle-K"])
def test_a_real_scene_is_right_within_its_sigmas_or_says_it_is_not(root, known, tmp_path, record_property):
    bench = load_bench()
    name = next(n for n, (folder, _) in bench.SCENES.items() if folder == require(root).name)
    scene = bench.SCENES[name][1](root)

    run = bench.match_and_calibrate(scene, "all", known, tmp_path)

    beyond = run.check.beyond() if run.check is not None else []
    record_property("outcome", f"{run.outcome.value}; {run.error}; beyond 3 sigma: {beyond[:5]}")
    assert run.outcome in HONEST, (run.outcome.value, run.error, run.check and run.check.level, beyond[:5])
