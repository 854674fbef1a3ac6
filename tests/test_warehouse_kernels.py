"""The compiled kernels of the warehouse (``sb3_crowdnav.sim.warehouse.kernels``) give the values of the NumPy and
float forms they replace, exactly, on generated layouts of wide ranges and on random and degenerate inputs; the graph
built from dicts is the graph networkx's methods build."""

from __future__ import annotations

import copy
import math
import pickle

import networkx as nx
import numpy as np
import pytest
from warehouse_reference import points_clearance, segment_meets_box, segments_miss_boxes

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.geometry import segment_distance_scalar
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.layout import LayoutRanges, Roadmap, generate_layout
from sb3_crowdnav.sim.warehouse.pickers import pick_slots
from sb3_crowdnav.sim.warehouse.roadmap import _BuiltGraph

WIDE = LayoutRanges(rows=(1, 4), segments=(1, 3), rack_length=(1.0, 8.0), rack_depth=(0.5, 2.0),
                    aisle_width=(1.0, 3.0), cross_aisle_width=(1.0, 3.0))


def layouts(count: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return [generate_layout(rng, WIDE if i % 2 else None) for i in range(count)]


# ---------------------------------------------------------------- the NumPy and float forms the kernels replace
def numpy_sense(segments: np.ndarray, p1: np.ndarray):
    ab = segments[:, 2:] - segments[:, :2]
    len2 = np.maximum(np.sum(ab**2, axis=1), 1e-18)
    dx, dy = p1[0] - segments[:, 0], p1[1] - segments[:, 1]
    t = np.minimum(np.maximum((dx * ab[:, 0] + dy * ab[:, 1]) / len2, 0.0), 1.0)
    d = np.hypot(dx - t * ab[:, 0], dy - t * ab[:, 1])
    return d, np.argsort(d, kind="stable")


def numpy_edges(corners: np.ndarray, sides: np.ndarray, boxes: np.ndarray):
    i, j = (np.arange(4, len(corners))[k] for k in np.triu_indices(len(corners) - 4, k=1))
    a, b = corners[i], corners[j]
    d = b - a
    turn = d[:, 0] * d[:, 1]
    keep = (sides[i] * turn <= 0) & (sides[j] * turn <= 0)
    i, j, a, b, d = i[keep], j[keep], a[keep], b[keep], d[keep]
    visible = segments_miss_boxes(a, b, boxes)
    return i[visible].tolist(), j[visible].tolist(), np.linalg.norm(d[visible], axis=1).tolist()


def float_joins(point, corners: np.ndarray, sides: np.ndarray, boxes: np.ndarray):
    (px, py), nodes, lengths = point, [], []
    for k in range(4, len(corners)):
        cx, cy = corners[k].tolist()
        dx, dy = px - cx, py - cy
        (sx0, sx1), (sy0, sy1) = sorted((px, cx)), sorted((py, cy))
        misses = not any(x0 < sx1 and sx0 < x1 and y0 < sy1 and sy0 < y1 and
                         segment_meets_box(px, py, cx - px, cy - py, (x0, y0, x1, y1), interior=True)
                         for x0, y0, x1, y1 in boxes.tolist())
        if sides[k] * dx * dy <= 0 and misses:
            nodes.append(k)
            lengths.append(math.sqrt(dx * dx + dy * dy))
    return nodes, lengths


def numpy_slots(segments: np.ndarray, spacing: float, offset: float) -> np.ndarray:
    (ax, ay), (ex, ey) = segments[:, :2].T, (segments[:, 2:] - segments[:, :2]).T
    length = np.hypot(ex, ey)
    count = np.where(length >= spacing, length // spacing, 0.0).astype(np.int64)
    edge = np.repeat(np.arange(len(count)), count)
    k = np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)
    ax, ay, ex, ey, length = ax[edge], ay[edge], ex[edge], ey[edge], length[edge]
    t = (k + 0.5) * length / count[edge]
    return np.stack([ax + ex * (t / length) + ey / length * offset, ay + ey * (t / length) + -ex / length * offset], axis=1)


# ---------------------------------------------------------------- the tests
def test_sense_is_the_numpy_distances_their_stable_order_and_the_swept_disc_test():
    rng = np.random.default_rng(1)
    radius, sensor_range, max_count = 0.3, 4.0, 16
    hits = 0
    for layout in layouts(60):
        segments = layout.segments
        ab = segments[:, 2:] - segments[:, :2]
        geometry = np.concatenate([segments[:, :2], ab, np.maximum(np.sum(ab**2, axis=1), 1e-18)[:, None], segments],
                                  axis=1)
        np.testing.assert_array_equal(kernels.segment_geometry(segments), geometry)
        w, h = layout.width / 2, layout.height / 2
        for _ in range(40):
            p0 = rng.uniform((-w, -h), (w, h))
            p1 = p0 + rng.normal(size=2) * 0.3
            reach = radius + math.dist(p0, p1)
            dist, order = np.zeros(len(segments)), np.zeros(len(segments), dtype=np.int64)
            hit, observed, mask = kernels.sense(geometry, *p0, *p1, reach, radius, sensor_range, max_count, dist, order)
            expected_d, expected_order = numpy_sense(segments, p1)
            np.testing.assert_array_equal(dist, expected_d)
            np.testing.assert_array_equal(order, expected_order)
            seen = min(max_count, int(np.count_nonzero(expected_d <= sensor_range)))
            np.testing.assert_array_equal(observed[:seen], segments[expected_order[:seen]])
            assert not observed[seen:].any() and mask.tolist() == [True] * seen + [False] * (max_count - seen)
            swept = any(segment_distance_scalar(p0, p1, s[:2], s[2:]) < radius for s in segments.tolist())
            assert hit == swept
            hits += hit
    assert 0 < hits < 60 * 40  # both answers were asked


def test_segment_distance_kernel_is_the_float_form():
    rng = np.random.default_rng(2)
    points = rng.choice(np.arange(-3.0, 3.5, 0.5), (3000, 8))  # on a grid: crossing, touching, collinear, degenerate
    points[:1000] = rng.uniform(-3, 3, (1000, 8))
    for p in points.tolist():
        assert kernels.segment_distance(*p) == segment_distance_scalar(p[0:2], p[2:4], p[4:6], p[6:8])


@pytest.mark.parametrize("clearance", [0.32, 0.4, 0.25])
def test_the_roadmaps_edges_and_joins_are_the_numpy_and_float_forms(clearance):
    rng = np.random.default_rng(3)
    checked = 0
    for layout in layouts(80, seed=4):
        roadmap = Roadmap(layout, clearance)
        if roadmap.grown is None:
            continue
        assert roadmap._edges() == numpy_edges(roadmap.corners, roadmap._sides, roadmap._open)
        w, h = layout.width / 2, layout.height / 2
        for point in [*rng.uniform((-w, -h), (w, h), (10, 2)).tolist(), *roadmap.corners[:6].tolist()]:
            nodes, lengths = kernels.joins(*point, roadmap.corners, roadmap._sides, 4, roadmap._open)
            assert (nodes.tolist(), lengths.tolist()) == float_joins(point, roadmap.corners, roadmap._sides,
                                                                    roadmap._open)
        checked += 1
    assert checked > 40


def test_slot_points_and_clearances_are_the_numpy_forms():
    rng = np.random.default_rng(5)
    for layout in layouts(200, seed=6):
        for radius in (0.25, 0.3, 0.31):
            spacing, offset = 2 * radius + 0.2, radius + 0.1
            expected = numpy_slots(layout.rack_segments, spacing, offset)
            np.testing.assert_array_equal(kernels.slot_points(layout.rack_segments, spacing, offset), expected)
            w, h = layout.width / 2, layout.height / 2
            points = np.concatenate([expected, rng.uniform((-w - 1, -h - 1), (w + 1, h + 1), (30, 2))])
            np.testing.assert_array_equal(kernels.points_clearance(points, layout.boxes, w, h),
                                          points_clearance(points, layout.boxes, (w, h)))
    assert len(pick_slots(layouts(1)[0], SceneConfig())) > 10


def adjacency(graph: nx.Graph) -> dict:
    return {u: list(nbrs.items()) for u, nbrs in graph.adj.items()}


def test_the_built_graph_is_the_graph_networkx_methods_build():
    """Same nodes, neighbours in the same order, shared edge dicts; A* finds the same paths; it copies and pickles
    (as a plain graph) and is refused nothing networkx's algorithms ask of a graph. With a route's ends: the graph
    add_weighted_edges_from of the ends' edges makes, the built graph unchanged."""
    rng, searched = np.random.default_rng(8), 0
    for layout in layouts(30, seed=7):
        roadmap = Roadmap(layout, 0.4)
        nodes, (i, j, w) = roadmap._nodes.tolist(), roadmap._edges()
        built = _BuiltGraph.from_edges(nodes, i, j, w)
        plain = nx.Graph()
        plain.add_nodes_from(nodes)
        plain.add_weighted_edges_from(zip(i, j, w, strict=True))
        assert list(built.nodes) == list(plain.nodes)
        assert adjacency(built) == adjacency(plain)
        assert all(built._adj[u][v] is built._adj[v][u] for u, v in built.edges)
        for source, target in zip(nodes, reversed(nodes), strict=True):
            if nx.has_path(plain, source, target):
                assert nx.astar_path(built, source, target) == nx.astar_path(plain, source, target)
        for other in (copy.deepcopy(built), pickle.loads(pickle.dumps(built)), built.copy()):
            assert nx.utils.graphs_equal(other, plain)
        before, n = adjacency(built), len(roadmap.corners)
        w_, h_ = layout.width / 2, layout.height / 2
        for start, goal in rng.uniform((-w_, -h_), (w_, h_), (8, 2, 2)).tolist():
            (a, la), (b, lb) = roadmap._joins(start), roadmap._joins(goal)
            ended = built.with_ends(n, a, la, b, lb)
            plain.add_weighted_edges_from([*((n, k, x) for k, x in zip(a, la, strict=True)),
                                           *((n + 1, k, x) for k, x in zip(b, lb, strict=True))])
            assert list(ended.nodes) == list(plain.nodes)
            assert all(ended._adj[u] == {v: d for v, d in plain._adj[u].items() if v != n} for u in nodes)
            if a and b:  # the same path as on the whole graph, with the roadmap's heuristic and without one
                assert ended._adj[n] == plain._adj[n]
                remaining = [*np.linalg.norm(roadmap.corners - goal, axis=1).tolist(), math.dist(start, goal), 0.0]
                for heuristic in (None, lambda u, _, remaining=remaining: remaining[u]):
                    try:
                        expected = nx.astar_path(plain, n, n + 1, heuristic=heuristic)
                    except nx.NetworkXNoPath:
                        continue
                    assert nx.astar_path(ended, n, n + 1, heuristic=heuristic) == expected
                    searched += 1
            plain.remove_nodes_from((n, n + 1))
            assert adjacency(built) == before
    assert searched > 20


def float_pressed(state: np.ndarray, room, grown, boxes, hall, radius) -> list[int]:
    from warehouse_reference import point_clearance as float_clearance

    (x0, y0, x1, y1), out = room, []
    for i, (x, y) in enumerate(state[:, :2].tolist()):
        if x0 < x < x1 and y0 < y < y1 and not any(a < x < c and b < y < d for a, b, c, d in grown):
            continue
        if float_clearance(x, y, [tuple(b) for b in boxes], hall) < radius:
            out.append(i)
    return out


def test_the_clearance_kernels_are_the_float_forms():
    """point_clearance and pressed exactly; segment_clearance within an ulp (its hypot is the C library's) and the same
    answer to every threshold the simulator asks; sense_and_follow's route bookkeeping is _advance_route's."""
    from warehouse_reference import point_clearance as float_clearance
    from warehouse_reference import segment_clearance as float_segment_clearance

    from sb3_crowdnav.sim.geometry import point_segment_distance_scalar

    rng = np.random.default_rng(9)
    pressed_seen = seen_off = seen_blocked = 0
    for layout in layouts(60, seed=10):
        boxes, (w, h), radius = layout.boxes, (layout.width / 2, layout.height / 2), 0.3
        listed = [tuple(b) for b in boxes.tolist()]
        points = np.concatenate([rng.uniform((-w - 0.5, -h - 0.5), (w + 0.5, h + 0.5), (200, 2)),
                                 boxes[:, :2] + rng.normal(size=(len(boxes), 2)) * 0.3])
        for x, y in points.tolist():
            assert kernels.point_clearance(x, y, boxes, w, h) == float_clearance(x, y, listed, (w, h))
        c = radius - 1e-6
        room, grown = np.array([-w + c, -h + c, w - c, h - c]), boxes + np.array([-c, -c, c, c])
        got = kernels.pressed(points, room, grown, boxes, w, h, c).tolist()
        assert got == float_pressed(points, room.tolist(), grown.tolist(), boxes, (w, h), c)
        pressed_seen += len(got)
        for a, b in zip(points[::2].tolist(), points[1::2].tolist(), strict=False):
            ours, theirs = kernels.segment_clearance(*a, *b, boxes, w, h, radius), float_segment_clearance(
                a, b, listed, (w, h), radius)
            assert ours == pytest.approx(theirs, rel=1e-15, abs=1e-15)
            assert (ours >= radius - 1e-6) == (theirs >= radius - 1e-6)
            # the route's bookkeeping of a step that ends at a: waypoints passed, strayed, blocked
            route = np.concatenate([[a], b + rng.normal(size=(3, 2)) * rng.choice([0.1, 1.0]), [b]])
            index = int(rng.integers(1, len(route)))
            dist, order = np.zeros(len(layout.segments)), np.zeros(len(layout.segments), dtype=np.int64)
            geometry = np.concatenate([layout.segments[:, :2], layout.segments[:, 2:] - layout.segments[:, :2],
                                       np.ones((len(layout.segments), 1)), layout.segments], axis=1)
            *_, new_index, off, blocked = kernels.sense_and_follow(
                geometry, *a, *a, radius, radius, 4.0, 16, dist, order, route, index, 0.5, 0.5, boxes, w, h)
            expected = index
            while expected < len(route) - 1 and math.dist(a, route[expected]) < 0.5:
                expected += 1
            assert new_index == expected
            assert off == (point_segment_distance_scalar(a, route[expected - 1], route[expected]) > 0.5)
            clearance = float_segment_clearance(a, route[expected].tolist(), listed, (w, h), radius)
            assert blocked == (not off and clearance < radius - 1e-6)
            seen_off, seen_blocked = seen_off + off, seen_blocked + blocked
    assert pressed_seen > 0 and seen_off > 0 and seen_blocked > 0  # every answer was asked


def test_the_small_kernels_are_their_numpy_forms():
    from warehouse_reference import separated

    rng = np.random.default_rng(11)
    for layout in layouts(100, seed=12):
        w, h = layout.width / 2, layout.height / 2
        for clearance in (0.0, 0.4, 1.5, 3.0):  # grown until they touch and leave the hall
            grown, inner = layout.boxes + np.array([-clearance, -clearance, clearance, clearance]), (-w, -h, w, h)
            assert kernels.separated(grown, *inner) == separated(grown, inner)
            hall = (-w + clearance, -h + clearance, w - clearance, h - clearance)
            apart, ours, corners, sides, opened = kernels.box_roadmap(layout.boxes, clearance, *hall)
            assert apart == separated(grown, hall)
            np.testing.assert_array_equal(ours, grown)
            np.testing.assert_array_equal(opened, grown + np.array([1e-6, 1e-6, -1e-6, -1e-6]))
            x0, y0, x1, y1 = hall
            expected = np.concatenate([[(x0, y0), (x0, y1), (x1, y1), (x1, y0)],
                                       grown[:, [0, 1, 2, 1, 2, 3, 0, 3]].reshape(-1, 2)])
            np.testing.assert_array_equal(corners, expected)
            np.testing.assert_array_equal(sides, [0.0] * 4 + [1.0, -1.0, 1.0, -1.0] * len(grown))
        roadmap = Roadmap(layout, 0.4)
        points = rng.uniform((-w, -h), (w, h), (64, 2))
        if roadmap.grown is not None:
            assert roadmap.free_points(points) == [roadmap.is_free(p) for p in points.tolist()]
        start, goal = points[0], points[1]
        expected = np.flatnonzero((np.hypot(*(points - start).T) >= 1.6) & (np.hypot(*(points - goal).T) >= 1.6))
        np.testing.assert_array_equal(kernels.far_from_both(points, *start, *goal, 1.6), expected)
        np.testing.assert_array_equal(kernels.distances_to(points, *goal), np.linalg.norm(points - goal, axis=1))


def test_py_hypot_is_cpythons_hypot_and_dist():
    """CPython 3.11's algorithm, bit for bit there (elsewhere within an ulp: later Pythons changed theirs)."""
    import sys

    rng = np.random.default_rng(13)
    values = np.concatenate([rng.normal(size=(40_000, 2)) * rng.choice([1e-6, 1e-2, 1.0, 10.0, 1e4], (40_000, 1)),
                             np.round(rng.normal(size=(20_000, 2)), 2), [[0.0, 0.0], [-0.0, 3.0], [3.0, -4.0]]])
    ours = np.array([kernels.py_hypot(x, y) for x, y in values.tolist()])
    theirs = np.array([math.hypot(x, y) for x, y in values.tolist()])
    if sys.version_info[:2] == (3, 11):
        np.testing.assert_array_equal(ours, theirs)
        assert [kernels.py_hypot(x - 0.5, y + 1.25) for x, y in values[:500].tolist()] == \
            [math.dist((x, y), (0.5, -1.25)) for x, y in values[:500].tolist()]
    np.testing.assert_allclose(ours, theirs, rtol=2.3e-16, atol=0)
    assert math.isnan(kernels.py_hypot(math.nan, 1.0)) and kernels.py_hypot(math.inf, math.nan) == math.inf


def float_preferences(positions, dwell, waypoint, routes, v_pref, arrival):
    """PickerCrowd.preferred_velocities in floats (the form the kernel replaces)."""
    out = []
    for i, (x, y) in enumerate(positions.tolist()):
        if dwell[i] > 0:
            out.append([0.0, 0.0])
            continue
        route, w = routes[i], waypoint[i]
        while w < len(route) - 1 and math.dist((x, y), route[w]) < arrival:
            w += 1
        waypoint[i] = w
        dx, dy = route[w][0] - x, route[w][1] - y
        norm = math.hypot(dx, dy)
        if norm > v_pref or (w < len(route) - 1 and norm > 1e-9):
            dx, dy = dx / norm * v_pref, dy / norm * v_pref
        out.append([dx, dy])
    return out


def test_the_picker_kernels_are_the_float_loops():
    """Preferred velocities (waypoints passed within reach, slowing into the last one, zero while standing) and the
    countdown with its events, against the loops they replace, on random routes and positions near waypoints."""
    rng = np.random.default_rng(14)
    events = {1: 0, 2: 0}
    for _ in range(300):
        n = int(rng.integers(1, 8))
        routes = [rng.uniform(-5, 5, (int(rng.integers(1, 6)), 2)).tolist() for _ in range(n)]
        array, lengths = np.zeros((n, 6, 2)), np.array([len(r) for r in routes], dtype=np.int64)
        for i, route in enumerate(routes):
            array[i, : len(route)] = route
        waypoint = rng.integers(0, lengths)
        near = np.array([routes[i][min(w + int(rng.integers(0, 2)), len(routes[i]) - 1)] for i, w in enumerate(waypoint)])
        positions = near + rng.normal(size=(n, 2)) * rng.choice([0.05, 0.2, 2.0])
        dwell = np.where(rng.random(n) < 0.4, rng.choice([0.1, 0.25, 1.0], n), 0.0)
        ours_w, theirs_w = waypoint.copy(), waypoint.tolist()
        ours = np.full((n, 2), np.nan)
        kernels.picker_preferences(positions, dwell, ours_w, array, lengths, 1.0, 0.25, ours)
        ours = ours.tolist()
        assert ours == float_preferences(positions, dwell, theirs_w, routes, 1.0, 0.25)
        assert ours_w.tolist() == theirs_w
        state = np.concatenate([positions, np.zeros((n, 2))], axis=1)
        ours_d = dwell.copy()
        which, what = kernels.picker_progress(state, ours_d, ours_w, array, lengths, 0.25, 0.25)
        expected = []
        for i, (x, y) in enumerate(positions.tolist()):
            if dwell[i] > 0:
                dwell[i] = max(0.0, dwell[i] - 0.25)
                if dwell[i] == 0:
                    expected.append((i, 1))
            elif theirs_w[i] == len(routes[i]) - 1 and math.dist((x, y), routes[i][-1]) < 0.25:
                expected.append((i, 2))
        assert list(zip(which.tolist(), what.tolist(), strict=True)) == expected
        np.testing.assert_array_equal(ours_d, dwell)
        for _, event in expected:
            events[event] += 1
    assert events[1] > 0 and events[2] > 0


def test_spread_is_the_greedy_float_loop():
    rng = np.random.default_rng(15)
    for _ in range(300):
        points = rng.uniform(-4, 4, (int(rng.integers(1, 40)), 2))
        points[::3] = np.round(points[::3] / 0.8) * 0.8  # on a grid of the spacing: distances at the threshold
        permutation, n = rng.permutation(len(points)), int(rng.integers(1, 12))
        chosen: list[int] = []
        for i in permutation.tolist():
            if all(math.hypot(points[i, 0] - points[k, 0], points[i, 1] - points[k, 1]) >= 0.8 for k in chosen):
                chosen.append(i)
                if len(chosen) == n:
                    break
        assert kernels.spread(points, permutation, n, 0.8).tolist() == chosen


def test_route_query_is_the_sight_test_the_joins_and_the_heuristic():
    rng = np.random.default_rng(16)
    direct = indirect = 0
    for layout in layouts(60, seed=17):
        roadmap = Roadmap(layout, 0.4)
        if roadmap.grown is None:
            continue
        w, h = layout.width / 2, layout.height / 2
        for start, goal in rng.uniform((-w - 0.3, -h - 0.3), (w + 0.3, h + 0.3), (10, 2, 2)).tolist():
            query = kernels.route_query(*start, *goal, roadmap.corners, roadmap._sides, 4, roadmap._open,
                                        roadmap._hall).tolist()
            assert bool(query[0]) == roadmap._visible_one(start, goal)
            if query[0]:
                direct += 1
                assert len(query) == 1
                continue
            indirect += 1
            a, b = int(query[1]), int(query[2])
            joins_s, joins_g = roadmap._joins(start), roadmap._joins(goal)
            assert ([int(k) for k in query[3 : 3 + a]], query[3 + a + b : 3 + 2 * a + b]) == joins_s
            assert ([int(k) for k in query[3 + a : 3 + a + b]], query[3 + 2 * a + b : 3 + 2 * (a + b)]) == joins_g
            dx, dy = start[0] - goal[0], start[1] - goal[1]
            heuristic = [*np.linalg.norm(roadmap.corners - goal, axis=1).tolist(), math.sqrt(dx * dx + dy * dy), 0.0]
            assert query[3 + 2 * (a + b) :] == heuristic
    assert direct > 0 and indirect > 0
