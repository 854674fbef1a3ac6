"""The compiled kernels (``sb3_crowdnav.sim.geometry``, ``sb3_crowdnav.sim.warehouse.kernels``) against the readable
forms of ``warehouse_reference`` (to rounding: relative tolerances of 1e-12, answers to thresholds compared away from
the threshold) and against properties, on generated layouts of wide ranges and on random and degenerate inputs; the
route search is networkx's A*."""

from __future__ import annotations

import itertools
import math

import networkx as nx
import numpy as np
import pytest
import warehouse_reference as reference
from shapely.geometry import LineString

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.geometry import (
    TIE_QUANTUM,
    nearest_segments,
    point_segment_distance,
    segment_distance,
    segment_to_segment,
    swept_clearance,
)
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.boxes import BoxSpace
from sb3_crowdnav.sim.warehouse.layout import LayoutRanges, Roadmap, generate_layout
from sb3_crowdnav.sim.warehouse.pickers import pick_slots

WIDE = LayoutRanges(rows=(1, 4), segments=(1, 3), rack_length=(1.0, 8.0), rack_depth=(0.5, 2.0),
                    aisle_width=(1.0, 3.0), cross_aisle_width=(1.0, 3.0))
RTOL = 1e-12  # the kernels' arithmetic need not be the references' operations in their order
NEAR = 1e-9  # [m] an answer to a threshold this close to it may differ by rounding: not compared


def layouts(count: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return [generate_layout(rng, WIDE if i % 2 else None) for i in range(count)]


def box_roadmaps(count: int, seed: int, clearance: float = 0.4):
    return [r for r in (Roadmap(layout, clearance) for layout in layouts(count, seed)) if isinstance(r.space, BoxSpace)]


# ---------------------------------------------------------------- distances
def test_segment_distance_is_the_reference_and_shapelys():
    """On a grid (crossing, touching, collinear, degenerate segments) and at random: the reference's value, shapely's
    distance, symmetric in the two segments and in their directions, zero where they cross."""
    rng = np.random.default_rng(2)
    points = rng.choice(np.arange(-3.0, 3.5, 0.5), (3000, 8))
    points[:1000] = rng.uniform(-3, 3, (1000, 8))
    p0, p1, q0, q1 = points[:, 0:2], points[:, 2:4], points[:, 4:6], points[:, 6:8]
    ours = segment_distance(p0, p1, q0, q1)
    np.testing.assert_allclose(ours, reference.segment_distance(p0, p1, q0, q1), rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(ours, segment_distance(q1, q0, p1, p0), rtol=RTOL, atol=1e-15)
    assert [segment_to_segment(*p) for p in points.tolist()] == ours.tolist()  # the array form loops over it
    for p in points[::10].tolist():
        expected = LineString([p[0:2], p[2:4]]).distance(LineString([p[4:6], p[6:8]]))
        assert segment_to_segment(*p) == pytest.approx(expected, rel=RTOL, abs=1e-12)
    assert (ours == 0).sum() > 100 and (ours > 0).sum() > 1000  # crossing and apart both asked


def test_the_array_forms_broadcast():
    rng = np.random.default_rng(3)
    p, a, b = rng.normal(size=(5, 1, 2)), rng.normal(size=(1, 7, 2)), rng.normal(size=(7, 2))
    ours = point_segment_distance(p, a, b)
    assert ours.shape == (5, 7)
    np.testing.assert_allclose(ours, reference.point_segment_distance(p, a, b), rtol=RTOL, atol=1e-15)
    assert point_segment_distance(np.zeros(2), np.array([1.0, -1.0]), np.array([1.0, 1.0])).shape == ()
    pos0, pos1 = rng.normal(size=(3, 4, 2)), rng.normal(size=(3, 4, 2))
    segments, mask = rng.normal(size=(3, 1, 6, 4)) * 2, rng.random((3, 1, 6)) < 0.6
    mask[0] = False
    clearance = swept_clearance(pos0, pos1, segments, mask)
    d = reference.segment_distance(pos0[..., None, :], pos1[..., None, :], segments[..., :2], segments[..., 2:])
    expected = np.where(mask, d, np.inf).min(axis=-1)
    assert clearance.shape == (3, 4) and np.isinf(clearance[0]).all()
    np.testing.assert_allclose(clearance, expected, rtol=RTOL, atol=1e-15)


# ---------------------------------------------------------------- the robot's step
def assert_distance_order(order: np.ndarray, dist: np.ndarray) -> None:
    """``order`` puts ``dist`` nearest first, distances closer than TIE_QUANTUM counted equal and taken by index."""
    assert sorted(order.tolist()) == list(range(len(dist)))
    d = dist[order]
    assert (np.diff(d) > -TIE_QUANTUM).all()
    tied = np.abs(np.diff(d)) < 1e-12
    assert (np.diff(order)[tied] > 0).all()


def test_sense_gives_the_distances_their_order_the_nearest_segments_and_the_swept_hit():
    rng = np.random.default_rng(1)
    radius, sensor_range, max_count = 0.3, 4.0, 16
    hits = 0
    for layout in layouts(60):
        segments = layout.segments
        w, h = layout.width / 2, layout.height / 2
        for _ in range(40):
            p0 = rng.uniform((-w, -h), (w, h))
            p1 = p0 + rng.normal(size=2) * 0.3
            reach = radius + math.dist(p0, p1)
            dist, order = np.zeros(len(segments)), np.zeros(len(segments), dtype=np.int64)
            sensed = kernels.sense(segments, *p0, *p1, reach, radius, sensor_range, max_count, dist, order)
            np.testing.assert_allclose(dist, reference.point_segment_distance(p1, segments[:, :2], segments[:, 2:]),
                                       rtol=RTOL, atol=1e-15)
            assert_distance_order(order, dist)
            seen = min(max_count, int(np.count_nonzero(dist <= sensor_range)))
            np.testing.assert_array_equal(sensed.observed[:seen], segments[order[:seen]])
            assert not sensed.observed[seen:].any() and sensed.mask.tolist() == [True] * seen + [False] * (max_count - seen)
            swept = reference.segment_distance(p0, p1, segments[:, :2], segments[:, 2:])
            if np.abs(swept - radius).min() > NEAR:
                assert sensed.hit == (swept.min() < radius)
            hits += sensed.hit
    assert 0 < hits < 60 * 40  # both answers were asked


def test_segments_equally_far_are_observed_in_index_order_whatever_their_last_bits():
    """The faces of an aisle seen from its centre line are equally far in exact arithmetic; their computed distances
    differ in the last bit (either way, and differently between machines). Both the kernel and nearest_segments
    order them by index, so the observation does not depend on those bits."""
    rng = np.random.default_rng(3)
    unequal = 0
    for _ in range(400):
        x0, width = rng.uniform(-10, 10), rng.uniform(0.5, 3.0)
        y0, y1 = rng.uniform(-10, -1), rng.uniform(1, 10)
        # the right face first, then the left: index order is not left-to-right
        segments = np.array([[x0 + width, y0, x0 + width, y1], [x0, y0, x0, y1], [x0 - 5.0, y0, x0 - 5.0, y1]])
        p = np.array([(x0 + (x0 + width)) / 2, rng.uniform(y0, y1)])
        dist, order = np.zeros(3), np.zeros(3, dtype=np.int64)
        sensed = kernels.sense(segments, *p, *p, 0.3, 0.3, 8.0, 2, dist, order)
        unequal += dist[0] != dist[1]
        assert order.tolist() == [0, 1, 2]
        np.testing.assert_array_equal(sensed.observed, segments[:2])
        observed, mask = nearest_segments(p, segments, 2, 8.0)
        np.testing.assert_array_equal(observed, segments[:2])
        assert mask.all()
    assert unequal > 50  # the last bits did differ (either way)


def test_the_clearance_kernels_are_the_float_forms_and_sense_and_follow_keeps_the_route():
    """point_clearance, pressed and segment_clearance to rounding; sense_and_follow's route bookkeeping: the
    waypoints passed, strayed from the leg, blocked on the way to the current waypoint."""
    rng = np.random.default_rng(9)
    pressed_seen = seen_off = seen_blocked = 0
    for layout in layouts(60, seed=10):
        boxes, (w, h), radius = layout.boxes, (layout.width / 2, layout.height / 2), 0.3
        listed = [tuple(b) for b in boxes.tolist()]
        points = np.concatenate([rng.uniform((-w - 0.5, -h - 0.5), (w + 0.5, h + 0.5), (200, 2)),
                                 boxes[:, :2] + rng.normal(size=(len(boxes), 2)) * 0.3])
        clearances = [kernels.point_clearance(x, y, boxes, w, h) for x, y in points.tolist()]
        expected = [reference.point_clearance(x, y, listed, (w, h)) for x, y in points.tolist()]
        np.testing.assert_allclose(clearances, expected, rtol=RTOL, atol=1e-15)
        c = radius - 1e-6
        room, grown = np.array([-w + c, -h + c, w - c, h - c]), boxes + np.array([-c, -c, c, c])
        got = set(kernels.pressed(points, room, grown, boxes, w, h, c).tolist())
        sure = [i for i, d in enumerate(expected) if abs(d - c) > NEAR]
        assert {i for i in sure if expected[i] < c} == got & set(sure)
        pressed_seen += len(got)
        for a, b in zip(points[::2].tolist(), points[1::2].tolist(), strict=False):
            ours = kernels.segment_clearance(*a, *b, boxes, w, h, radius)
            assert ours == pytest.approx(reference.segment_clearance(a, b, listed, (w, h), radius), rel=RTOL, abs=1e-15)
            route = np.concatenate([[a], b + rng.normal(size=(3, 2)) * rng.choice([0.1, 1.0]), [b]])
            index = int(rng.integers(1, len(route)))
            dist, order = np.zeros(len(layout.segments)), np.zeros(len(layout.segments), dtype=np.int64)
            step = kernels.sense_and_follow(layout.segments, *a, *a, radius, radius, 4.0, 16, dist, order, route, index,
                                            0.5, 0.5, boxes, w, h)
            gaps = [math.dist(a, p) for p in route[index:-1].tolist()]
            if min([abs(g - 0.5) for g in gaps], default=1.0) < NEAR:
                continue
            expected_index = index
            while expected_index < len(route) - 1 and math.dist(a, route[expected_index]) < 0.5:
                expected_index += 1
            assert step.index == expected_index
            leg = float(reference.point_segment_distance(np.array(a), route[expected_index - 1], route[expected_index]))
            clearance = reference.segment_clearance(a, route[expected_index].tolist(), listed, (w, h), radius)
            if abs(leg - 0.5) > NEAR and abs(clearance - (radius - 1e-6)) > NEAR:
                assert step.off == (leg > 0.5)
                assert step.blocked == (not step.off and clearance < radius - 1e-6)
            seen_off, seen_blocked = seen_off + step.off, seen_blocked + step.blocked
    assert pressed_seen > 0 and seen_off > 0 and seen_blocked > 0  # every answer was asked


# ---------------------------------------------------------------- the roadmap
@pytest.mark.parametrize("clearance", [0.32, 0.4, 0.25])
def test_the_roadmaps_edges_and_joins_are_the_references(clearance):
    rng = np.random.default_rng(3)
    roadmaps = box_roadmaps(80, seed=4, clearance=clearance)
    for roadmap in roadmaps:
        space = roadmap.space
        i, j, lengths = space.edges()
        ref_i, ref_j, ref_lengths = reference.bitangent_edges(space.corners, space.sides, space.opened)
        assert (i, j) == (ref_i, ref_j)
        np.testing.assert_allclose(lengths, ref_lengths, rtol=RTOL)
        w, h = roadmap.layout.width / 2, roadmap.layout.height / 2
        for point in [*rng.uniform((-w, -h), (w, h), (10, 2)).tolist(), *space.corners[:6].tolist()]:
            nodes, lengths = kernels.joins(*point, space.corners, space.sides, 4, space.opened)
            ref_nodes, ref_lengths = reference.joins(point, space.corners, space.sides, space.opened)
            assert nodes.tolist() == ref_nodes
            np.testing.assert_allclose(lengths, ref_lengths, rtol=RTOL)
    assert len(roadmaps) > 40


def test_route_query_is_the_sight_test_the_joins_and_the_heuristic():
    rng = np.random.default_rng(16)
    direct = indirect = 0
    for roadmap in box_roadmaps(60, seed=17):
        space, w, h = roadmap.space, roadmap.layout.width / 2, roadmap.layout.height / 2
        for start, goal in rng.uniform((-w - 0.3, -h - 0.3), (w + 0.3, h + 0.3), (10, 2, 2)).tolist():
            query = space.query(start, goal)
            assert isinstance(query, kernels.RouteQuery) and query.direct == space.sees(start, goal)
            if query.direct:
                direct += 1
                assert not (len(query.start_joins) or len(query.goal_joins) or len(query.heuristic))
                continue
            indirect += 1
            assert (query.start_joins.tolist(), query.start_lengths.tolist()) == space.joins(start)
            assert (query.goal_joins.tolist(), query.goal_lengths.tolist()) == space.joins(goal)
            nodes = np.concatenate([space.corners, [start, goal]])
            np.testing.assert_allclose(query.heuristic, np.hypot(*(nodes - goal).T), rtol=RTOL, atol=0)
            assert query.heuristic[-1] == 0.0
    assert direct > 0 and indirect > 0


def test_box_roadmap_and_the_small_kernels_are_their_references():
    rng = np.random.default_rng(11)
    for layout in layouts(100, seed=12):
        w, h = layout.width / 2, layout.height / 2
        for clearance in (0.0, 0.4, 1.5, 3.0):  # grown until they touch and leave the hall
            grown, inner = layout.boxes + np.array([-clearance, -clearance, clearance, clearance]), (-w, -h, w, h)
            assert kernels.separated(grown, *inner) == reference.separated(grown, inner)
            hall = (-w + clearance, -h + clearance, w - clearance, h - clearance)
            geometry = kernels.box_roadmap(layout.boxes, clearance, *hall)
            assert geometry.apart == reference.separated(grown, hall)
            np.testing.assert_allclose(geometry.grown, grown, rtol=RTOL)
            np.testing.assert_allclose(geometry.opened, grown + np.array([1e-6, 1e-6, -1e-6, -1e-6]), rtol=RTOL)
            x0, y0, x1, y1 = hall
            expected = np.concatenate([[(x0, y0), (x0, y1), (x1, y1), (x1, y0)],
                                       grown[:, [0, 1, 2, 1, 2, 3, 0, 3]].reshape(-1, 2)])
            np.testing.assert_allclose(geometry.corners, expected, rtol=RTOL)
            np.testing.assert_array_equal(geometry.sides, [0.0] * 4 + [1.0, -1.0, 1.0, -1.0] * len(grown))
        roadmap = Roadmap(layout, 0.4)
        points = rng.uniform((-w, -h), (w, h), (64, 2))
        assert roadmap.free_points(points) == [roadmap.is_free(p) for p in points.tolist()]
        start, goal = points[0], points[1]
        expected = np.flatnonzero((np.hypot(*(points - start).T) >= 1.6) & (np.hypot(*(points - goal).T) >= 1.6))
        np.testing.assert_array_equal(kernels.far_from_both(points, *start, *goal, 1.6), expected)
        np.testing.assert_allclose(kernels.distances_to(points, *goal), np.linalg.norm(points - goal, axis=1), rtol=RTOL)


def _networkx_astar(n, i, j, w, start, goal, heuristic):
    """networkx's A* from node n to node n + 1 on the graph of nodes 0 .. n - 1 and edges i-j of lengths w, the ends'
    edges added after them (the start's, then the goal's); None without a path."""
    graph = nx.Graph()
    graph.add_nodes_from(range(n))
    graph.add_weighted_edges_from(zip(i, j, w, strict=True))
    graph.add_weighted_edges_from([*((n, k, x) for k, x in zip(*start, strict=True)),
                                   *((n + 1, k, x) for k, x in zip(*goal, strict=True))])
    try:
        return nx.astar_path(graph, n, n + 1, heuristic=lambda u, _: heuristic[u])
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        return None


def _search(n, i, j, w, start, goal, heuristic):
    path = kernels.astar_route(*kernels.adjacency(n, np.array(i, dtype=np.int64), np.array(j, dtype=np.int64),
                                                  np.array(w, dtype=np.float64)),
                               np.array(start[0], dtype=np.int64), np.array(start[1], dtype=np.float64),
                               np.array(goal[0], dtype=np.int64), np.array(goal[1], dtype=np.float64),
                               np.asarray(heuristic, dtype=np.float64)).tolist()
    return path or None


def test_the_compiled_search_is_networkx_astar_on_random_graphs():
    """The same path as ``nx.astar_path`` on the same graph, ties included: random graphs with small integer lengths
    (many equally short paths), with no heuristic, an admissible one and an inconsistent one (which re-enqueues
    explored nodes), ends without joins, and graphs with no way through."""
    rng, found, missing, tied = np.random.default_rng(8), 0, 0, 0
    for _ in range(400):
        n = int(rng.integers(1, 14))
        pairs = [(a, b) for a in range(n) for b in range(a + 1, n) if rng.random() < rng.uniform(0.1, 0.6)]
        i, j = [a for a, _ in pairs], [b for _, b in pairs]
        w = rng.integers(1, 4, len(pairs)).astype(float).tolist()
        start_nodes = sorted(rng.choice(n, int(rng.integers(0, min(n, 3) + 1)), replace=False).tolist())
        goal_nodes = rng.permutation(rng.choice(n, int(rng.integers(0, min(n, 3) + 1)), replace=False)).tolist()
        start = (start_nodes, rng.integers(1, 4, len(start_nodes)).astype(float).tolist())
        goal = (goal_nodes, rng.integers(1, 4, len(goal_nodes)).astype(float).tolist())
        for heuristic in (np.zeros(n + 2), rng.uniform(0.0, 1.0, n + 2), rng.uniform(0.0, 6.0, n + 2)):
            heuristic[n + 1] = 0.0
            expected = _networkx_astar(n, i, j, w, start, goal, heuristic.tolist())
            assert _search(n, i, j, w, start, goal, heuristic) == expected
            found, missing = found + (expected is not None), missing + (expected is None)
            tied += expected is not None and heuristic.max() == 0 and \
                len(list(itertools.islice(_equally_short(n, i, j, w, start, goal), 2))) > 1
    assert found > 300 and missing > 50 and tied > 20


def _equally_short(n, i, j, w, start, goal):
    graph = nx.Graph()
    graph.add_weighted_edges_from(zip(i, j, w, strict=True))
    graph.add_weighted_edges_from([*((n, k, x) for k, x in zip(*start, strict=True)),
                                   *((n + 1, k, x) for k, x in zip(*goal, strict=True))])
    return nx.all_shortest_paths(graph, n, n + 1, weight="weight")


def test_the_compiled_search_is_networkx_astar_on_roadmaps():
    """On generated layouts' roadmaps, the corners joined to random ends with the straight distance to the goal as the
    heuristic (the roadmap's search): the path ``nx.astar_path`` finds."""
    rng, searched = np.random.default_rng(8), 0
    for layout in layouts(30, seed=7):
        roadmap = Roadmap(layout, 0.4)
        (i, j, w), n = roadmap.space.edges(), len(roadmap.corners)
        w_, h_ = layout.width / 2, layout.height / 2
        for start, goal in rng.uniform((-w_, -h_), (w_, h_), (8, 2, 2)).tolist():
            ends = roadmap.space.joins(start), roadmap.space.joins(goal)
            remaining = [*np.linalg.norm(roadmap.corners - goal, axis=1).tolist(), math.dist(start, goal), 0.0]
            expected = _networkx_astar(n, i, j, w, *ends, remaining)
            assert _search(n, i, j, w, *ends, remaining) == expected
            searched += expected is not None
    assert searched > 50


# ---------------------------------------------------------------- the pickers
def test_slot_points_and_points_clearance_are_the_references():
    rng = np.random.default_rng(5)
    for layout in layouts(200, seed=6):
        for radius in (0.25, 0.3, 0.31):
            spacing, offset = 2 * radius + 0.2, radius + 0.1
            expected = reference.slot_points(layout.rack_segments, spacing, offset)
            np.testing.assert_allclose(kernels.slot_points(layout.rack_segments, spacing, offset), expected,
                                       rtol=RTOL, atol=1e-12)
            w, h = layout.width / 2, layout.height / 2
            points = np.concatenate([expected, rng.uniform((-w - 1, -h - 1), (w + 1, h + 1), (30, 2))])
            np.testing.assert_allclose(kernels.points_clearance(points, layout.boxes, w, h),
                                       reference.points_clearance(points, layout.boxes, (w, h)), rtol=RTOL, atol=1e-15)
    assert len(pick_slots(layouts(1)[0], SceneConfig())) > 10


def random_pickers(rng: np.random.Generator):
    n = int(rng.integers(1, 8))
    routes = [rng.uniform(-5, 5, (int(rng.integers(1, 6)), 2)).tolist() for _ in range(n)]
    array, lengths = np.zeros((n, 6, 2)), np.array([len(r) for r in routes], dtype=np.int64)
    for i, route in enumerate(routes):
        array[i, : len(route)] = route
    waypoint = rng.integers(0, lengths)
    near = np.array([routes[i][min(w + int(rng.integers(0, 2)), len(routes[i]) - 1)] for i, w in enumerate(waypoint)])
    positions = near + rng.normal(size=(n, 2)) * rng.choice([0.05, 0.2, 2.0])
    dwell = np.where(rng.random(n) < 0.4, rng.choice([0.1, 0.25, 1.0], n), 0.0)
    return routes, array, lengths, waypoint, positions, dwell


def test_the_picker_kernels_are_the_float_loops():
    """Preferred velocities (waypoints passed within reach, slowing into the last one, zero while standing) and the
    countdown with its events, against the reference loops, on random routes and positions near waypoints."""
    rng = np.random.default_rng(14)
    events = {1: 0, 2: 0}
    for _ in range(300):
        routes, array, lengths, waypoint, positions, dwell = random_pickers(rng)
        ours_w, theirs_w = waypoint.copy(), waypoint.tolist()
        ours = np.full((len(routes), 2), np.nan)
        v_prefs, arrivals = rng.uniform(0.5, 2.0, len(routes)), rng.uniform(0.1, 0.8, len(routes))  # per picker
        kernels.picker_preferences(positions, dwell, ours_w, array, lengths, v_prefs, arrivals, ours)
        np.testing.assert_allclose(ours, reference.preferences(positions, dwell, theirs_w, routes, v_prefs.tolist(),
                                                               arrivals.tolist()), rtol=RTOL, atol=1e-15)
        assert ours_w.tolist() == theirs_w
        assert (np.linalg.norm(ours, axis=1) <= v_prefs * (1 + 1e-12)).all()  # never faster than its v_pref
        state = np.concatenate([positions, np.zeros((len(routes), 2))], axis=1)
        ours_d = dwell.copy()
        which, what = kernels.picker_progress(state, ours_d, ours_w, array, lengths, 0.25, arrivals)
        expected = []
        for i, (x, y) in enumerate(positions.tolist()):
            if dwell[i] > 0:
                dwell[i] = max(0.0, dwell[i] - 0.25)
                if dwell[i] == 0:
                    expected.append((i, 1))
            elif theirs_w[i] == len(routes[i]) - 1 and math.dist((x, y), routes[i][-1]) < arrivals[i]:
                expected.append((i, 2))
        assert list(zip(which.tolist(), what.tolist(), strict=True)) == expected
        np.testing.assert_array_equal(ours_d, dwell)
        for _, event in expected:
            events[event] += 1
    assert events[1] > 0 and events[2] > 0


def test_picker_after_step_is_pressed_then_progress():
    """Named results: the pressed pickers, and the events only when none is pressed."""
    rng = np.random.default_rng(18)
    layout = layouts(1, seed=19)[0]
    w, h, c = layout.width / 2, layout.height / 2, 0.3 - 1e-6
    room, grown = np.array([-w + c, -h + c, w - c, h - c]), layout.boxes + np.array([-c, -c, c, c])
    asked = {True: 0, False: 0}
    for _ in range(200):
        routes, array, lengths, waypoint, positions, dwell = random_pickers(rng)
        if rng.random() < 0.5:  # one picker on a rack
            positions[0] = layout.boxes[0, :2] + 0.05
        state = np.concatenate([positions, np.zeros((len(routes), 2))], axis=1)
        before_d, before_w = dwell.copy(), waypoint.copy()
        arrivals = np.full(len(routes), 0.25)
        after = kernels.picker_after_step(state, room, grown, layout.boxes, w, h, c, dwell, waypoint, array, lengths,
                                          0.25, arrivals)
        assert isinstance(after, kernels.AfterStep)
        assert after.pressed.tolist() == kernels.pressed(state, room, grown, layout.boxes, w, h, c).tolist()
        if len(after.pressed):
            assert not len(after.which) and not len(after.what)
            np.testing.assert_array_equal(dwell, before_d)  # nothing counted down
        else:
            which, what = kernels.picker_progress(state, before_d, before_w, array, lengths, 0.25, arrivals)
            assert after.which.tolist() == which.tolist() and after.what.tolist() == what.tolist()
        asked[bool(len(after.pressed))] += 1
    assert asked[True] > 0 and asked[False] > 0


def test_spread_takes_points_greedily_at_least_the_spacing_apart():
    """In the permutation's order, each point taken when it is at least the spacing from every point taken before,
    until n are taken (a point within rounding of the spacing may go either way)."""
    rng = np.random.default_rng(15)
    for _ in range(300):
        points = rng.uniform(-4, 4, (int(rng.integers(1, 40)), 2))
        points[::3] = np.round(points[::3] / 0.8) * 0.8  # on a grid of the spacing: distances at the threshold
        permutation, n = rng.permutation(len(points)), int(rng.integers(1, 12))
        chosen = kernels.spread(points, permutation, n, 0.8).tolist()
        assert len(chosen) <= n and len(set(chosen)) == len(chosen)
        position = {int(k): r for r, k in enumerate(permutation)}
        assert chosen == sorted(chosen, key=position.get)  # in the permutation's order
        for r, b in enumerate(chosen):
            assert all(math.dist(points[b], points[k]) >= 0.8 - NEAR for k in chosen[:r])
        last = position[chosen[-1]] if len(chosen) == n else len(points)
        for k in permutation[:last].tolist():  # every point skipped before the end was too near one taken before it
            if k not in chosen:
                assert any(math.dist(points[k], points[c]) < 0.8 + NEAR for c in chosen if position[c] < position[k])
