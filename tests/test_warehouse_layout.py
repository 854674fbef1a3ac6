"""Warehouse layouts: generation, validation at construction, layout files, the roadmap's routes."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon

from sb3_crowdnav.sim.warehouse import LayoutRanges, Roadmap, WarehouseLayout, generate_layout
from sb3_crowdnav.sim.warehouse.boxes import BoxSpace
from sb3_crowdnav.sim.warehouse.roadmap import PolygonSpace

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "warehouse_layout.yaml"
ROBOT_RADIUS = 0.3


def _rect(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


@pytest.mark.parametrize("seed", range(20))
def test_generated_layouts_are_valid_and_within_their_ranges(seed):
    ranges = LayoutRanges()
    layout = generate_layout(np.random.default_rng(seed), ranges)
    layout.validate(ROBOT_RADIUS)
    assert len(layout.polygons) == len(layout.racks) + 4  # racks, then the four walls
    for vertices in layout.polygons:
        x, y = vertices[:, 0], vertices[:, 1]
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # counter-clockwise
    sizes = np.array([np.ptp(r, axis=0) for r in layout.racks])  # (n, 2): length along x, depth along y
    assert np.all((ranges.rack_length[0] <= sizes[:, 0]) & (sizes[:, 0] <= ranges.rack_length[1] + 1e-9))
    assert np.all((ranges.rack_depth[0] <= sizes[:, 1]) & (sizes[:, 1] <= ranges.rack_depth[1] + 1e-9))
    rows = len({round(float(r[:, 1].min()), 6) for r in layout.racks})
    assert ranges.rows[0] <= rows <= ranges.rows[1]


def test_same_seed_same_layout_other_seeds_differ():
    a, b = (generate_layout(np.random.default_rng(7)) for _ in range(2))
    assert a.to_dict() == b.to_dict()
    others = {json.dumps(generate_layout(np.random.default_rng(s)).to_dict()) for s in range(10)}
    assert len(others) == 10


@pytest.mark.parametrize(("racks", "message"), [
    ([_rect(-6, -1, 6, 1)], "not inside the 10 x 10 m hall"),
    ([np.array([[0, 0], [2, 2], [2, 0], [0, 2]])], "not a simple polygon"),  # a bow tie
    ([_rect(-3, -1, -0.3, 1), _rect(0.2, -1, 3, 1)], "aisle between racks\\[0\\] and racks\\[1\\] is 0.50 m"),
    ([_rect(-5, -4.5, 5, -2)], "between racks\\[0\\] and the wall is 0.50 m"),
    ([_rect(-5, -1, 0, 1), _rect(0, -1, 5, 1)], "split into 2 parts"),  # two racks wall to wall
])
def test_infeasible_layouts_are_refused_with_the_reason(racks, message):
    layout = WarehouseLayout(width=10, height=10, racks=tuple(racks))
    with pytest.raises(ValueError, match=message):
        layout.validate(ROBOT_RADIUS)


def test_a_gap_touching_zero_is_a_closed_gap_not_a_narrow_one():
    # a rack against the wall and two racks back to back are fine; the robot cannot be between them anyway
    layout = WarehouseLayout(10, 10, (_rect(-5, -5, -2, -4), _rect(-2, -5, 1, -4)))
    layout.validate(ROBOT_RADIUS)


def test_bad_values_are_named():
    with pytest.raises(ValueError, match="width must be > 0"):
        WarehouseLayout(width=-1, height=5)
    with pytest.raises(ValueError, match="racks\\[0\\] must be a \\(k, 2\\) array"):
        WarehouseLayout(5, 5, (np.zeros((2, 2)),))
    with pytest.raises(ValueError, match="rows\\[1\\] must be >= 3"):
        LayoutRanges(rows=(3, 2))
    with pytest.raises(ValueError, match="rack_length must be a \\(min, max\\) range"):
        LayoutRanges(rack_length=(5.0, 4.0))
    with pytest.raises(ValueError, match="unknown keys \\['shelves'\\]"):
        WarehouseLayout.from_dict({"width": 5, "height": 5, "shelves": []})


def test_layout_files_round_trip(tmp_path):
    layout = WarehouseLayout.from_file(EXAMPLE)
    layout.validate(ROBOT_RADIUS)
    assert (layout.width, layout.height, len(layout.racks)) == (16.0, 10.0, 5)
    np.testing.assert_allclose(np.ptp(layout.racks[0], axis=0), [5.0, 1.0])
    path = tmp_path / "copy.json"
    path.write_text(json.dumps(layout.to_dict()))
    again = WarehouseLayout.from_file(path)
    assert again.to_dict() == layout.to_dict()
    bad = tmp_path / "bad.txt"
    bad.write_text("{}")
    with pytest.raises(ValueError, match=r"must end in \.json, \.yaml or \.yml"):
        WarehouseLayout.from_file(bad)
    with pytest.raises(ValueError, match="no file"):
        WarehouseLayout.from_file(tmp_path / "missing.yaml")


@pytest.mark.parametrize("seed", range(5))
def test_routes_stay_in_the_free_space_of_the_robot(seed):
    rng = np.random.default_rng(seed)
    layout = generate_layout(rng)
    clearance = ROBOT_RADIUS + 0.05
    roadmap = Roadmap(layout, clearance)
    free = roadmap.free
    corners = [(-layout.width / 2 + 0.8, -layout.height / 2 + 0.8), (layout.width / 2 - 0.8, layout.height / 2 - 0.8)]
    route = roadmap.route(*corners)
    np.testing.assert_allclose(route[0], corners[0])
    np.testing.assert_allclose(route[-1], corners[1])
    for a, b in itertools.pairwise(route):
        assert free.buffer(1e-6).covers(LineString([a, b]))  # no segment cuts through a rack or a wall
    straight = float(np.linalg.norm(np.subtract(*corners)))
    assert straight <= roadmap.route_length(route) < 2 * straight


def test_no_route_between_disconnected_regions():
    split = WarehouseLayout(10, 10, (_rect(-5, -0.5, 5, 0.5),))  # not validated: a rack from wall to wall
    roadmap = Roadmap(split, ROBOT_RADIUS)
    with pytest.raises(ValueError, match="no route"):
        roadmap.route((0, -3), (0, 3))


# ---------------------------------------------------------------------- the fast geometry of box racks
def _as_polygons(layout):
    """The same layout with a midpoint added to every rack's first edge: not boxes, so every test goes to shapely."""
    return WarehouseLayout(layout.width, layout.height,
                           tuple(np.insert(r, 1, (r[0] + r[1]) / 2, axis=0) for r in layout.racks))


def _points(rng, layout, n):
    """Points anywhere in the hall, and some on the racks' grown corners and sides (the boundary cases)."""
    w, h = layout.width / 2, layout.height / 2
    near = [c + rng.normal(0, 1e-3, 2) for r in layout.racks for c in r + np.sign(r - r.mean(axis=0)) * 0.32]
    return np.concatenate([rng.uniform((-w, -h), (w, h), (n, 2)), near])


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("clearance", [ROBOT_RADIUS + 0.1, ROBOT_RADIUS + 0.02])
def test_the_box_roadmap_routes_as_the_shapely_one(seed, clearance):
    """Generated racks are boxes: corners from the grown boxes, visibility by clipping, only bitangent edges. The
    same corners (shapely's buffers within an ulp), a subgraph of the full visibility graph with the same weights,
    routes of the same length."""
    rng = np.random.default_rng(seed)
    layout = generate_layout(rng)
    fast, slow = Roadmap(layout, clearance), Roadmap(_as_polygons(layout), clearance)
    assert isinstance(fast.space, BoxSpace) and isinstance(slow.space, PolygonSpace)
    assert len(fast.corners) == len(slow.corners)
    gaps = np.linalg.norm(fast.corners[:, None] - slow.corners[None], axis=2)
    index = gaps.argmin(axis=1)  # the shapely corner of each of ours
    assert gaps.min(axis=1).max() < 1e-12 and len(set(index.tolist())) == len(index)
    full = {frozenset((index[u], index[v])): d for u, v, d in fast.graph.edges(data="weight")}
    assert all(slow.graph.edges[tuple(e)]["weight"] == pytest.approx(d, abs=1e-12) for e, d in full.items())
    points = _points(rng, layout, 30)
    free = slow.free.buffer(1e-9)
    for a, b in itertools.pairwise(points):
        assert fast.is_free(a) == slow.is_free(a)
        assert fast.space.sees(a, b) == slow.space.sees(a, b)
        ours, theirs = fast.route(a, b), slow.route(a, b)
        assert Roadmap.route_length(ours) == pytest.approx(Roadmap.route_length(theirs), abs=1e-9)
        assert (ours[0] == a).all() and (ours[-1] == b).all()
        if fast.is_free(a) and fast.is_free(b):
            assert all(free.covers(LineString(s)) for s in itertools.pairwise(ours))
    ours = [fast.route(a, b) for a, b in itertools.pairwise(points)]  # the joins are remembered now
    again = Roadmap(layout, clearance)
    assert all((r == again.route(a, b)).all() for r, (a, b) in zip(ours, itertools.pairwise(points), strict=True))


@pytest.mark.parametrize("seed", range(5))
def test_free_space_tests_of_boxes_agree_with_shapely(seed):
    import shapely

    from sb3_crowdnav.sim.warehouse import kernels
    from sb3_crowdnav.sim.warehouse.boxes import in_free_space

    rng = np.random.default_rng(seed)
    layout = generate_layout(rng)
    points = _points(rng, layout, 300)
    obstacles = shapely.union_all([*layout.rack_polygons, layout.hall.exterior])
    exact = shapely.distance(obstacles, shapely.points(points))
    exact[~shapely.contains_xy(layout.hall, points[:, 0], points[:, 1])] = 0.0
    exact[shapely.contains_xy(shapely.union_all(layout.rack_polygons), points[:, 0], points[:, 1])] = 0.0
    hall = (layout.width / 2, layout.height / 2)
    np.testing.assert_allclose(np.maximum(kernels.points_clearance(points, layout.boxes, *hall), 0.0), exact, atol=1e-12)
    for clearance in (0.3 - 1e-6, 0.301, 0.3):
        free = layout.free_space(clearance)
        assert (in_free_space(layout, points, clearance) == shapely.contains_xy(free, points[:, 0], points[:, 1])).all()
    boxes, racks = layout.boxes, shapely.union_all(layout.rack_polygons)
    for a, b in itertools.pairwise(points):
        segment = LineString([a, b])
        if layout.hall.covers(segment):
            expected = 0.0 if racks.intersects(segment) else shapely.distance(obstacles, segment)
            assert kernels.segment_clearance(*a, *b, boxes, *hall, 100.0) == pytest.approx(expected, abs=1e-9)


def test_polygons_are_oriented_as_shapely_orients_them():
    import shapely

    clockwise = _rect(-2, -1, 2, 1)[::-1]
    closed = np.concatenate([_rect(3, -1, 4, 1), _rect(3, -1, 4, 1)[:1]])
    layout = WarehouseLayout(12, 6, (clockwise, closed, _rect(-5, -1, -4, 1)))
    for ours, rack in zip(layout.polygons, layout.racks, strict=False):
        np.testing.assert_array_equal(ours, np.asarray(shapely.geometry.polygon.orient(Polygon(rack)).exterior.coords)[:-1])
    assert layout.boxes is None  # the closed ring has five vertices: not a box


@pytest.mark.parametrize("seed", range(3))
def test_a_remembered_slot_route_is_the_route_planned_afresh(seed):
    from sb3_crowdnav.sim.config import SceneConfig
    from sb3_crowdnav.sim.warehouse.pickers import PickSlots

    rng = np.random.default_rng(seed)
    layout = generate_layout(rng)
    slots = PickSlots(layout, SceneConfig(scenario="warehouse"), 0.32)
    pairs = rng.integers(len(slots.points), size=(40, 2)).tolist()
    first = [slots.route(i, j) for i, j in pairs]
    assert all(slots.route(i, j) is route for (i, j), route in zip(pairs, first, strict=True))  # remembered
    fresh = Roadmap(layout, 0.32)
    for (i, j), route in zip(pairs, first, strict=True):
        np.testing.assert_array_equal(route, fresh.route(slots.points[i], slots.points[j])[1:])
        assert route[-1] == slots.points[j].tolist()


# ---------------------------------------------------------------------- the roadmap's search without networkx's graph
def _networkx_route(roadmap, start, goal):
    """The route as the roadmap planned it with networkx: its graph, the ends joined with add_weighted_edges_from
    (the start's edges, then the goal's), nx.astar_path with the straight distance to the goal, the ends removed."""
    import networkx as nx

    start, goal = np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
    if roadmap.space.sees(start, goal):
        return np.stack([start, goal])
    (from_start, start_lengths), (to_goal, goal_lengths) = roadmap.space.joins(start), roadmap.space.joins(goal)
    if len(roadmap.corners) and not (from_start and to_goal):
        if not from_start:
            nearest = roadmap.corners[np.argmin(np.linalg.norm(roadmap.corners - start, axis=1))]
            return np.concatenate([start[None], _networkx_route(roadmap, nearest, goal)])
        nearest = roadmap.corners[np.argmin(np.linalg.norm(roadmap.corners - goal, axis=1))]
        return np.stack([start, goal]) if (nearest == start).all() else \
            np.concatenate([_networkx_route(roadmap, start, nearest), goal[None]])
    graph, n = roadmap.graph, len(roadmap.corners)
    points = np.concatenate([roadmap.corners, start[None], goal[None]])
    remaining = np.linalg.norm(points - goal, axis=1).tolist()
    try:
        graph.add_weighted_edges_from(itertools.chain(
            zip([n] * len(from_start), from_start, start_lengths, strict=True),
            zip([n + 1] * len(to_goal), to_goal, goal_lengths, strict=True)))
        path = nx.astar_path(graph, n, n + 1, heuristic=lambda u, _: remaining[u])
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        raise ValueError("no route") from None
    finally:
        graph.remove_nodes_from((n, n + 1))
    return points[path]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("polygons", [False, True])
def test_routes_are_networkx_astar_paths(seed, polygons):
    """Routes in floats (``waypoints``) and arrays (``route``) are the former array program's paths (the same one among
    equally short ones: regular layouts have many) between free points, pick slots, corners, points in racks and
    outside the hall."""
    from sb3_crowdnav.sim.config import SceneConfig
    from sb3_crowdnav.sim.warehouse.pickers import pick_slots

    rng = np.random.default_rng(seed)
    layout = generate_layout(rng)
    slots = pick_slots(layout, SceneConfig(scenario="warehouse"))
    if polygons:
        layout = _as_polygons(layout)
    ours, theirs = Roadmap(layout, 0.32), Roadmap(layout, 0.32)
    points = np.concatenate([_points(rng, layout, 40), slots[rng.integers(len(slots), size=30)],
                             ours.corners[rng.integers(len(ours.corners), size=10)],
                             rng.uniform(-20, 20, (5, 2))])
    rng.shuffle(points)
    for a, b in itertools.pairwise(points):
        try:
            expected = _networkx_route(theirs, a, b)
        except ValueError:
            with pytest.raises(ValueError, match="no route"):
                ours.route(a, b)
            continue
        route = ours.route(a, b)
        np.testing.assert_array_equal(route, expected)
        assert ours.waypoints(a, b) == expected.tolist()


def test_the_search_finds_no_route_where_networkx_finds_none():
    split = WarehouseLayout(10, 10, (_rect(-5, -0.5, 5, 0.5), _rect(-3, 2, 3, 3)))  # not validated: split in two
    roadmap = Roadmap(split, ROBOT_RADIUS)
    for a, b in [((0, -3), (0, 4)), ((-4, 1.5), (0, -2))]:
        with pytest.raises(ValueError, match="no route"):
            roadmap.route(a, b)
        with pytest.raises(ValueError, match="no route"):
            _networkx_route(Roadmap(split, ROBOT_RADIUS), a, b)


def test_route_length_is_the_sum_of_the_legs():
    rng = np.random.default_rng(0)
    for n in range(1, 14):
        for _ in range(30):
            route = rng.uniform(-10, 10, (n, 2)) * 10.0 ** rng.uniform(-2, 1, (n, 1))
            expected = sum(math.dist(a, b) for a, b in itertools.pairwise(route.tolist()))
            assert Roadmap.route_length(route) == pytest.approx(expected, rel=1e-12, abs=0)
            assert Roadmap.route_length(route.tolist()) == Roadmap.route_length(route)
    assert Roadmap.route_length([[0.0, 0.0], [3.0, 4.0], [3.0, 0.0]]) == pytest.approx(9.0, rel=1e-15)


@pytest.mark.parametrize("seed", range(5))
def test_a_layouts_segments_are_its_polygons_edges(seed):
    """The cached segments (built from one vertex array for a generated layout) are polygon_segments' of the racks and
    the hall, read-only; a layout built from the same racks one by one has the same racks, segments and boxes."""
    from sb3_crowdnav.sim.geometry import polygon_segments

    layout = generate_layout(np.random.default_rng(seed))
    plain = WarehouseLayout(layout.width, layout.height, tuple(np.array(r) for r in layout.racks))
    for ours in (layout, plain):
        np.testing.assert_array_equal(ours.segments, polygon_segments([*layout.racks, layout.hall_vertices]))
        np.testing.assert_array_equal(ours.rack_segments, polygon_segments(layout.rack_vertices))
        assert not ours.segments.flags.writeable and not any(r.flags.writeable for r in ours.racks)
    np.testing.assert_array_equal(layout.boxes, plain.boxes)
    assert all((a == b).all() for a, b in zip(layout.racks, plain.racks, strict=True))
    with pytest.raises(ValueError, match="non-finite"):
        WarehouseLayout(10, 10, np.array([_rect(-1, -1, 1, 1) * np.nan]))


def test_the_one_segment_clippings_are_segments_miss_boxes():
    """The roadmap's clipping of one segment (kernels.misses_boxes: the graph's edges, joins, sight) answers as the
    NumPy clipping, on random segments and on degenerate ones: along the boxes' sides, through their corners,
    axis-parallel, of zero length."""
    from warehouse_reference import segments_miss_boxes

    from sb3_crowdnav.sim.warehouse.kernels import misses_boxes

    rng = np.random.default_rng(0)
    for _ in range(40):
        corners = np.sort(rng.uniform(-5, 5, (6, 2, 2)), axis=1)  # (box, lo/hi, x/y)
        boxes = corners.reshape(6, 4)  # xmin, ymin, xmax, ymax
        xs = np.concatenate([corners[:, :, 0].ravel(), rng.uniform(-6, 6, 6)])
        ys = np.concatenate([corners[:, :, 1].ravel(), rng.uniform(-6, 6, 6)])
        a = np.stack([rng.choice(xs, 500), rng.choice(ys, 500)], axis=1)
        b = np.stack([rng.choice(xs, 500), rng.choice(ys, 500)], axis=1)
        b[:100, 0], b[100:200, 1], b[200:220] = a[:100, 0], a[100:200, 1], a[200:220]
        a, b = np.concatenate([a, rng.uniform(-6, 6, (200, 2))]), np.concatenate([b, rng.uniform(-6, 6, (200, 2))])
        expected = segments_miss_boxes(a, b, boxes).tolist()
        assert [misses_boxes(*p, *q, boxes) for p, q in zip(a.tolist(), b.tolist(), strict=True)] == expected
