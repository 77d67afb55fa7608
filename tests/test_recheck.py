"""Placed views checked against the network: a view at a wrong pose is placed again or left out by name."""

import numpy as np
import pytest

from camnet.model.projection import look_at
from camnet.model.resection import twin_poses
from camnet.model.triangulation import triangulate_missing
from camnet.solve.start.recheck import Network, recheck_placed

F_PX = 1500.0
RING_M = 0.6
N_VIEWS = 8
THRESHOLD_PX = 8.0


def ring(seed: int = 0):
    """(X (T, 3), R (M, 3, 3), C (M, 3), rows (T, M), xy (n, 2)): a 10 cm object seen by a ring of views 0.6 m
    round it, 45 degrees apart; each track is seen by the views that face its side (0.3 px noise)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-0.05, 0.05, (600, 3))
    angles = np.radians(45.0 * np.arange(N_VIEWS))
    C = RING_M * np.stack([np.cos(angles), np.sin(angles), 0.2 * np.ones(N_VIEWS)], axis=1)
    R = np.stack([look_at(c, np.zeros(3), up=(0.0, 0.0, -1.0))[0] for c in C])
    normals = X / np.linalg.norm(X, axis=1, keepdims=True)
    seen = np.einsum("ti,mi->tm", normals, C / np.linalg.norm(C, axis=1, keepdims=True)) > 0.2
    rows = np.full(seen.shape, -1)
    t_idx, c_idx = np.nonzero(seen)
    rows[t_idx, c_idx] = np.arange(len(t_idx))
    xc = np.einsum("nij,nj->ni", R[c_idx], X[t_idx] - C[c_idx])
    xy = F_PX * xc[:, :2] / xc[:, 2:3] + rng.normal(0.0, 0.3, (len(t_idx), 2))
    return X, R, C, rows, xy


def network(R, C, rows, xy) -> Network:
    M = len(C)
    X = np.full((len(rows), 3), np.nan)
    placed = np.ones(M, dtype=bool)
    triangulate_missing(list(range(M)), xy, rows, np.full(M, F_PX), R, C, X, placed)
    return Network(list(range(M)), xy, rows, np.full(M, F_PX), R.copy(), C.copy(), X, placed)


def recheck(net: Network):
    which = np.arange(N_VIEWS) >= 2  # the scale pair frames the network
    return recheck_placed(net, which, f_free=np.zeros(N_VIEWS, dtype=bool), width_px=np.full(N_VIEWS, 640),
                          threshold_px=THRESHOLD_PX)


def rotation_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(A @ B.T) - 1) / 2, -1, 1))))


def test_a_network_placed_right_is_left_as_it_is():
    _, R, C, rows, xy = ring()
    net = network(R, C, rows, xy)
    before = net.C.copy()

    assert recheck(net) == ({}, [])
    np.testing.assert_array_equal(net.C, before)


@pytest.mark.parametrize("wrong", [4, 6])
def test_a_view_at_its_neighbours_viewpoint_is_placed_again_at_its_own(wrong):
    # As the temple ring's templeSR0002 can be, resected at its neighbour's viewpoint on points of undetermined
    # depth: the points placed with it agree with it, the other views' do not (docs/benchmarks.md, "Real
    # images: the temple ring").
    _, R, C, rows, xy = ring()
    R_bad, C_bad = R.copy(), C.copy()
    R_bad[wrong], C_bad[wrong] = R[wrong - 1], C[wrong - 1]
    net = network(R_bad, C_bad, rows, xy)

    left_out, moved = recheck(net)

    assert (left_out, moved) == ({}, [wrong])
    assert np.linalg.norm(net.C[wrong] - C[wrong]) < 0.005
    assert rotation_deg(net.R[wrong], R[wrong]) < 0.3
    assert net.placed.all()
    np.testing.assert_array_equal(np.delete(net.C, wrong, axis=0), np.delete(C, wrong, axis=0))


def test_a_view_whose_observations_fit_no_pose_is_left_out_with_the_reason():
    _, R, C, rows, xy = ring()
    xy = xy.copy()
    mine = rows[rows[:, 5] >= 0, 5]
    xy[mine] = np.random.default_rng(1).uniform(-320, 320, (len(mine), 2))  # its tracks are false
    net = network(R, C, rows, xy)

    left_out, moved = recheck(net)

    assert moved == [] and list(left_out) == [5]
    assert left_out[5].startswith("its observations stand out") and "no consistent pose" in left_out[5]
    assert not net.placed[5] and net.placed[np.arange(N_VIEWS) != 5].all()
    # Its tracks' points now rest on the other views alone.
    others = np.flatnonzero((rows[:, 5] >= 0) & (np.sum(rows[:, np.arange(N_VIEWS) != 5] >= 0, axis=1) >= 2))
    assert np.all(np.isfinite(net.X[others]))


def test_nearly_flat_points_give_the_pose_and_its_mirrored_twin():
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.3, 0.3, (80, 2)), rng.normal(0.0, 0.002, 80)])  # a plane, 2 mm rough
    C = np.array([0.8, 0.3, -2.0])
    R = look_at(C, np.zeros(3))[0]
    xc = (X - C) @ R.T
    xy = F_PX * xc[:, :2] / xc[:, 2:3]

    poses = twin_poses(X, xy, F_PX)

    assert len(poses) == 2
    errors = sorted(np.linalg.norm(c - C) for _, c in poses)
    assert errors[0] < 0.02 and errors[1] > 0.2  # the pose, and a twin far from it
    assert twin_poses(np.column_stack([X[:, :2], rng.uniform(-0.3, 0.3, 80)]), xy, F_PX) == []  # not flat
