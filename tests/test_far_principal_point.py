"""A freed principal point that ends far from where it was given: no linear scale sigma, and the camera named."""

import numpy as np

from camnet.solve.bundle import CentreMode, Problem, State
from camnet.solve.report import assemble as diagnostics


def _problem_and_state(pp_px):
    intr = np.zeros((2, 9))
    intr[:, 0], intr[:, 1] = 1500.0, 1.0
    intr[:, 2:4] = pp_px
    intr_free = np.zeros((2, 9), dtype=bool)
    intr_free[:, [0, 2, 3]] = True
    problem = Problem(np.zeros(1, int), np.zeros(1, int), np.zeros((1, 2)), intr_free, np.zeros((2, 3), bool),
                      np.array([CentreMode.FIXED, CentreMode.ON_BASELINE]), 0.2, 1)
    state = State(intr, np.stack([np.eye(3)] * 2), np.array([[0, 0, 0], [0.2, 0, 0.0]]), np.zeros((1, 3)))
    return problem, state


def test_a_principal_point_moved_a_fifth_of_the_image_is_flagged_and_one_near_the_centre_is_not():
    size, centre = np.array([640.0, 480.0]), np.array([320.0, 240.0])
    problem, state = _problem_and_state(np.array([[330.0, 250.0], [320.0, 145.0]]))  # 1.6-2% and 20% off
    assert diagnostics._far_pp_rel(problem, state, 0, centre, size) == 0.0
    assert abs(diagnostics._far_pp_rel(problem, state, 1, centre, size) - 95 / 480) < 1e-9
    held = Problem(problem.cam, problem.pt, problem.uv, np.zeros((2, 9), bool), problem.rot_free,
                   problem.centre_mode, 0.2, 1)
    assert diagnostics._far_pp_rel(held, state, 1, centre, size) == 0.0  # held where given: nothing to flag
