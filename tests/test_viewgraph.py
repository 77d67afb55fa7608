"""The view graph: which pairs of a calibrated rig are matched, from geometry and from history."""

from __future__ import annotations

from collections import Counter
from itertools import combinations

import numpy as np
import pytest

from camnet.matching.viewgraph import ViewGraph, ViewGraphConfig, choose_pairs
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.model.overlap import axis_angles_deg, depth_ranges, frustum_overlap, overlapping_pairs
from camnet.model.projection import look_at

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 255.5], [0.0, 0.0, 1.0]])  # 65 degrees across 640 px


def camera(name: str, centre, target) -> Camera:
    R, t = look_at(np.asarray(centre, float), np.asarray(target, float))
    return Camera(name, 640, 512, K, np.zeros(5), R, t)


def ring(m: int, radius_m: float = 2.0) -> tuple[list[Camera], np.ndarray]:
    """`m` cameras evenly on a ring about a person-sized cylinder at the origin, and points on it."""
    angles = 2 * np.pi * np.arange(m) / m
    cameras = [camera(f"c{k}", (radius_m * np.sin(a), -0.2, -radius_m * np.cos(a)), (0, 0, 0))
               for k, a in enumerate(angles)]
    rng = np.random.default_rng(0)
    phi = rng.uniform(0, 2 * np.pi, 800)
    points = np.column_stack([0.25 * np.cos(phi), rng.uniform(-0.8, 0.8, 800), 0.17 * np.sin(phi)])
    return cameras, points


def test_depth_ranges_follow_x_cam_equals_R_X_plus_t():
    front = camera("front", (0, 0, 0), (0, 0, 1))
    back = camera("back", (0, 0, 0), (0, 0, -1))
    moved = Camera("moved", 640, 512, K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, -1.0]))  # centre at z = +1
    points = np.column_stack([np.zeros(50), np.zeros(50), np.linspace(1.0, 3.0, 50)])
    ranges = depth_ranges([front, back, moved], points, percentiles=(0.0, 100.0))
    np.testing.assert_allclose(ranges[0], [1.0, 3.0])
    assert np.isnan(ranges[1]).all()  # every point behind it
    # t = (0, 0, -1): the points at depths z - 1; the one at its centre is not in front.
    np.testing.assert_allclose(ranges[2], [2.0 / 49, 2.0])


def test_parallel_neighbours_overlap_and_far_apart_ones_do_not():
    """Same orientation; the far camera would share the view at infinity, not in the scene's depth range."""
    left, right = camera("l", (0, 0, 0), (0, 0, 1)), camera("r", (0.3, 0, 0), (0.3, 0, 1))
    far = camera("far", (10, 0, 0), (10, 0, 1))
    rng = np.random.default_rng(1)
    points = np.concatenate([rng.uniform([-1, -1, 2], [1.3, 1, 3], (300, 3)),
                             rng.uniform([9, -1, 2], [11, 1, 3], (300, 3))])
    overlap = frustum_overlap([left, right, far], depth_ranges([left, right, far], points))
    assert overlap[0, 1] > 0.5 and overlap[1, 0] > 0.5
    assert overlap[0, 2] == 0 and overlap[2, 0] == 0
    assert overlapping_pairs([left, right, far], points) == [(0, 1)]


def test_ring_pairs_are_neighbours_and_grow_linearly():
    counts = {}
    for m in (8, 16, 32):
        cameras, points = ring(m)
        pairs = overlapping_pairs(cameras, points, neighbours=4)
        counts[m] = len(pairs)
        assert all((k, (k + 1) % m) in pairs or ((k + 1) % m, k) in pairs for k in range(m))  # each ring neighbour
        angles = axis_angles_deg(cameras)
        assert all(angles[i, j] <= 75.0 for i, j in pairs)  # never across the ring
        assert (0, m // 2) not in pairs
    assert counts[8] < 28
    assert counts[32] <= 4 * 32 // 2 * 1.01 and counts[32] <= 2.2 * counts[16]


def arc(m: int) -> tuple[list[Camera], np.ndarray]:
    """`m` cameras on an arc of 150 degrees 0.6 m round one small object (config/hosts16.yaml's kind): every
    camera sees every other's view of it."""
    angles = np.radians(np.linspace(-75.0, 75.0, m))
    cameras = [camera(f"c{k:02d}", (0.6 * np.sin(a), 0.1 * (-1) ** k, -0.6 * np.cos(a)), (0, 0, 0))
               for k, a in enumerate(angles)]
    points = np.random.default_rng(2).uniform(-0.06, 0.06, (500, 3))
    return cameras, points


def test_an_arc_round_one_object_matches_a_linear_number_of_pairs():
    # Each camera's best partners, united, gave 33 pairs of 16 such cameras (41 with 4 partners each).
    for m in (8, 16, 32):
        cameras, points = arc(m)
        pairs = overlapping_pairs(cameras, points, neighbours=3)
        degree = Counter(k for pair in pairs for k in pair)
        assert len(pairs) <= 3 * m // 2, (m, len(pairs))
        assert min(degree[k] for k in range(m)) >= 2
        reached = {0}  # and connected: tracks still run along the whole arc
        for _ in range(m):
            reached |= {k for pair in pairs if reached & set(pair) for k in pair}
        assert reached == set(range(m))
    # Counted as the node chooses them once calibrated, where every pair matched well at the cold start:
    # the geometry's pairs (4 partners each at most), topped up from those, and one explored.
    counts = {}
    for m in (8, 16, 32):
        cameras, points = arc(m)
        graph = ViewGraph(always={frozenset(("c00", "c01"))})
        graph.update(Calibration(tuple(cameras), np.arange(len(points)), points, 0.5, "c00"))
        ids = [c.id for c in cameras]
        counts[m] = len(graph.pairs(ids, matched_well={frozenset(p) for p in combinations(ids, 2)}))
    assert all(counts[m] <= 4 * m // 2 + 2 for m in counts), counts
    assert counts[32] <= 2 * counts[16] + 1, counts


def test_pairs_that_matched_well_give_every_camera_a_partner_before_any_a_second():
    # Four cameras 90 degrees apart round a person: the geometry pairs none, every pair matched well.
    ids = ["a", "b", "c", "d"]
    chosen, _ = choose_pairs(ids, calibrated=ids, overlapping=(), always={frozenset("ab")},
                             matched_well={frozenset(p) for p in combinations(ids, 2)}, neighbours=2)
    assert Counter(camera for pair in chosen for camera in pair) == dict.fromkeys(ids, 2)
    # d, which the calibration puts elsewhere, keeps 2 of the pairs it matched well though a, b and c are full.
    triangle = {frozenset("ab"), frozenset("bc"), frozenset("ac")}
    chosen, _ = choose_pairs(ids, calibrated=ids, overlapping=triangle,
                             matched_well={frozenset(p) for p in combinations(ids, 2)}, neighbours=2)
    assert Counter(camera for pair in chosen for camera in pair)["d"] == 2


def test_a_camera_that_sees_no_point_has_no_pair():
    cameras, points = ring(8)
    away = camera("away", (0, 0, -2), (0, 0, -5))
    pairs = overlapping_pairs([*cameras, away], points)
    assert all(8 not in pair for pair in pairs)


def test_choose_pairs_cold_start_new_camera_and_exploration():
    ids = ["a", "b", "c", "d", "e"]
    everything = {frozenset(p) for p in combinations(ids, 2)}
    chosen, _ = choose_pairs(ids, calibrated=(), overlapping=(), explore=0)
    assert chosen == everything
    overlapping = {frozenset("ab"), frozenset("bc")}
    chosen, _ = choose_pairs(ids, calibrated="abcd", overlapping=overlapping, always={frozenset("ad")})
    assert chosen == overlapping | {frozenset("ad")} | {frozenset((x, "e")) for x in "abcd"}  # e: new
    # The rest (cd, ac, bd) come round in rotation, two per frame set.
    seen, cursor = set(), 0
    for _ in range(2):
        chosen, cursor = choose_pairs(ids, calibrated=ids, overlapping=overlapping,
                                      matched_well={frozenset("de"), frozenset("ae"), frozenset("be"),
                                                    frozenset("ce"), frozenset("ad")}, explore=2, cursor=cursor)
        assert len(chosen) == 7 + 2
        seen |= chosen
    assert seen == everything


def test_pairs_that_matched_well_do_not_keep_every_pair_of_an_arc():
    # Sixteen cameras that all see one object: every pair matched well at the cold start.
    ids = [f"c{k:02d}" for k in range(16)]
    everything = {frozenset(p) for p in combinations(ids, 2)}
    ring_pairs = {frozenset((ids[k], ids[(k + 1) % 16])) for k in range(16)}
    chosen, _ = choose_pairs(ids, calibrated=ids, overlapping=ring_pairs, matched_well=everything, neighbours=4)
    degree = Counter(camera for pair in chosen for camera in pair)
    assert ring_pairs <= chosen and max(degree.values()) <= 4 + 1 and len(chosen) <= 16 * 4 // 2 + 16
    # A camera the geometry gives no partner still keeps the pairs it matched well.
    chosen, _ = choose_pairs(ids, calibrated=ids, overlapping=ring_pairs - {p for p in ring_pairs if "c05" in p},
                             matched_well={frozenset(("c05", "c09"))}, neighbours=4)
    assert frozenset(("c05", "c09")) in chosen


def test_view_graph_matches_everything_until_a_calibration():
    cameras, points = ring(8)
    graph = ViewGraph(ViewGraphConfig(explore_per_set=1), always={frozenset(("c0", "c1"))})
    ids = [c.id for c in cameras]
    assert graph.pairs(ids) is None
    graph.update(Calibration(tuple(cameras), np.arange(len(points)), points, 0.5, "c0"))
    first, second = graph.pairs(ids), graph.pairs(ids)
    assert frozenset(("c0", "c4")) not in graph.overlapping
    assert len(first) == len(graph.overlapping) + 1 < 28 and first != second  # one explored pair, rotating
    assert graph.pairs([*ids, "new"]) >= {frozenset((c, "new")) for c in ids}


def test_config_is_checked():
    with pytest.raises(ValueError):
        ViewGraphConfig(neighbours=0)
    with pytest.raises(ValueError):
        overlapping_pairs(ring(4)[0], ring(4)[1], min_overlap=2.0)
