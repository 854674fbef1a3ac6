"""Warehouse layouts: generation, validation at construction, layout files, the roadmap's routes."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString

from sb3_crowdnav.sim.warehouse import LayoutRanges, Roadmap, WarehouseLayout, generate_layout

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
