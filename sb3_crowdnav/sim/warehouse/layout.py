"""Warehouse layouts: a walled hall with rectangular racks in rows, main and cross aisles, validated at construction.

The hall is centred at the origin: x in [-width/2, width/2], y in [-height/2, height/2] [m]. Racks are
polygons in world metres; a generated layout has ``rows`` rows of racks along x, separated by main aisles
(along x) and cut by cross aisles (along y) at the same x positions in every row, with end aisles between
the rack ends and the side walls:

    wall | end aisle | rack | cross aisle | rack | end aisle | wall      (one row; rows stacked in y,
                                                                         a main aisle between rows and
                                                                         between the outer rows and the walls)

Every layout, generated or given, is checked by :meth:`WarehouseLayout.validate` before use: polygons
simple, of positive area and inside the hall; every gap between two racks, or between a rack and a wall,
either closed (touching) or at least the robot's diameter + ``margin`` wide; and the free space of a
robot of that radius connected. Any violation is a ``ValueError`` naming the parameter.

Geometry is `shapely`'s; routes are shortest paths on a grid roadmap of the free space (`networkx`).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon, box

from sb3_crowdnav.sim.config import check_int, check_number
from sb3_crowdnav.sim.warehouse.boxes import rack_boxes, segment_meets_box, segments_miss_boxes, separated


@dataclass(frozen=True)
class LayoutRanges:
    """Ranges from which :func:`generate_layout` draws a layout (uniformly; integers inclusive) [m].

    :param rows: rows of racks
    :param segments: racks per row (``segments - 1`` cross aisles)
    :param rack_length: length of one rack along x
    :param rack_depth: depth of a rack along y (a double-sided rack)
    :param aisle_width: width of the main aisles (between rows, and between the outer rows and the walls)
    :param cross_aisle_width: width of the cross aisles and of the end aisles at the side walls
    """

    rows: tuple[int, int] = (2, 3)
    segments: tuple[int, int] = (1, 2)
    rack_length: tuple[float, float] = (4.0, 6.0)
    rack_depth: tuple[float, float] = (0.8, 1.2)
    aisle_width: tuple[float, float] = (1.8, 2.4)
    cross_aisle_width: tuple[float, float] = (1.8, 2.4)

    def __post_init__(self) -> None:
        for name in ("rows", "segments"):
            lo, hi = _pair(name, getattr(self, name))
            check_int(f"{name}[0]", lo, 1)
            check_int(f"{name}[1]", hi, lo)
        for name in ("rack_length", "rack_depth", "aisle_width", "cross_aisle_width"):
            lo, hi = _pair(name, getattr(self, name))
            check_number(f"{name}[0]", lo)
            check_number(f"{name}[1]", hi)
            if hi < lo:
                raise ValueError(f"{name} must be a (min, max) range with min <= max, got {getattr(self, name)!r}")


def _pair(name: str, value: Any) -> tuple[Any, Any]:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a (min, max) pair, got {value!r}")
    return value[0], value[1]


@dataclass(frozen=True)
class WarehouseLayout:
    """A walled hall and its racks (static obstacles), in world metres.

    :param width: hall size along x [m]
    :param height: hall size along y [m]
    :param racks: rack polygons, each a (k, 2) sequence of vertices (k >= 3), inside the hall
    """

    width: float
    height: float
    racks: tuple[np.ndarray, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        check_number("width", self.width)
        check_number("height", self.height)
        racks = []
        for i, rack in enumerate(self.racks):
            vertices = np.asarray(rack, dtype=np.float64)
            if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3 or not np.isfinite(vertices).all():
                raise ValueError(f"racks[{i}] must be a (k, 2) array of finite vertices with k >= 3, got shape "
                                 f"{vertices.shape}")
            vertices.setflags(write=False)
            racks.append(vertices)
        object.__setattr__(self, "racks", tuple(racks))

    # ------------------------------------------------------------------ geometry
    @property
    def hall(self) -> Polygon:
        return box(-self.width / 2, -self.height / 2, self.width / 2, self.height / 2)

    @property
    def hall_vertices(self) -> np.ndarray:
        """The hall's (4, 2) vertices, counter-clockwise, as ``np.asarray(hall.exterior.coords)[:-1]`` gives them."""
        return _box_vertices(-self.width / 2, -self.height / 2, self.width / 2, self.height / 2)

    @property
    def rack_polygons(self) -> list[Polygon]:
        return [Polygon(r) for r in self.racks]

    @property
    def wall_polygons(self) -> list[np.ndarray]:
        """The four outer walls as thin rectangles (0.2 m) outside the hall, (4, 2) vertices each."""
        w, h, t = self.width / 2, self.height / 2, 0.2
        rects = ((-w - t, -h - t, w + t, -h), (-w - t, h, w + t, h + t), (-w - t, -h, -w, h), (w, -h, w + t, h))
        return [_box_vertices(*r) for r in rects]

    @functools.cached_property
    def polygons(self) -> list[np.ndarray]:
        """Every static obstacle (the racks, then the four walls) as a (k, 2) vertex array, counter-clockwise
        (a clockwise one reversed as shapely's ``orient`` does: the first vertex kept, the others backwards)."""
        out = []
        for v in self.racks:
            v = v[:-1] if len(v) > 3 and (v[0] == v[-1]).all() else v  # a closed ring: shapely drops the repeat
            p = v.tolist()
            clockwise = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(p, p[1:] + p[:1], strict=True)) < 0
            out.append(np.concatenate([v[:1], v[:0:-1]]) if clockwise else np.array(v))
        return out + self.wall_polygons  # counter-clockwise already

    @functools.cached_property
    def boxes(self) -> np.ndarray | None:
        """(B, 4) ``[xmin, ymin, xmax, ymax]`` of the racks when all are axis-aligned rectangles (every generated
        layout), else None: the fast geometry of :mod:`~sb3_crowdnav.sim.warehouse.boxes` applies."""
        return rack_boxes(self.racks)

    @functools.cached_property
    def open_floor(self) -> Any:
        """The hall minus the racks (computed once per layout)."""
        return self.hall.difference(shapely.union_all(self.rack_polygons)) if self.racks else self.hall

    def free_space(self, clearance: float = 0.0, join_style: str = "round") -> Any:
        """The hall minus the racks, shrunk by ``clearance`` [m] (the centres a disc of that radius may take);
        remembered per clearance, as a layout is immutable."""
        cache = self.__dict__.setdefault("_free_spaces", {})
        key = (float(clearance), join_style)
        if key not in cache:
            floor = self.open_floor
            cache[key] = floor.buffer(-clearance, join_style=join_style) if clearance > 0 else floor
        return cache[key]

    # ------------------------------------------------------------------ validation
    def validate(self, robot_radius: float, margin: float = 0.2, name: str = "layout") -> None:
        """``ValueError`` naming ``name`` unless the layout is one a robot of ``robot_radius`` can drive in."""
        check_number("robot_radius", robot_radius)
        check_number("margin", margin, allow_zero=True)
        hall = self.hall
        polys = self.rack_polygons
        for i, poly in enumerate(polys):
            if not poly.is_valid or poly.area <= 0:
                raise ValueError(f"{name}: racks[{i}] is not a simple polygon of positive area")
            if not hall.contains(poly):
                raise ValueError(f"{name}: racks[{i}] is not inside the {self.width} x {self.height} m hall")
        min_gap = 2 * robot_radius + margin
        corners = np.asarray(hall.exterior.coords)
        walls = [LineString(corners[k : k + 2]) for k in range(4)]  # each side on its own: touching one is no excuse
        for i, poly in enumerate(polys):
            for wall in walls:
                gap = poly.distance(wall)
                if 1e-9 < gap < min_gap:
                    raise ValueError(f"{name}: the gap between racks[{i}] and the wall is {gap:.2f} m, narrower than "
                                     f"the robot's diameter + margin ({min_gap:.2f} m)")
            for j in range(i + 1, len(polys)):
                gap = poly.distance(polys[j])
                if 1e-9 < gap < min_gap:
                    raise ValueError(f"{name}: the aisle between racks[{i}] and racks[{j}] is {gap:.2f} m wide, "
                                     f"narrower than the robot's diameter + margin ({min_gap:.2f} m)")
        free = self.free_space(robot_radius)
        parts = len(getattr(free, "geoms", [free])) if not free.is_empty else 0
        if parts != 1:
            raise ValueError(f"{name}: the free space of a robot of radius {robot_radius} m is "
                             f"{'empty' if parts == 0 else f'split into {parts} parts'}; it must be connected")

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict[str, Any]:
        """Plain values: ``{"width": ..., "height": ..., "racks": [[[x, y], ...], ...]}``."""
        return {"width": float(self.width), "height": float(self.height),
                "racks": [r.tolist() for r in self.racks]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], name: str = "layout") -> WarehouseLayout:
        """From :meth:`to_dict`'s format; a rack may also be ``{"rect": [xmin, ymin, xmax, ymax]}``."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{name} must be a mapping with keys width, height, racks; got {type(data).__name__}")
        unknown = sorted(set(data) - {"width", "height", "racks"})
        missing = sorted({"width", "height"} - set(data))
        if unknown or missing:
            raise ValueError(f"{name}: unknown keys {unknown}, missing keys {missing}; allowed: width, height, racks")
        racks = []
        for i, rack in enumerate(data.get("racks") or []):
            if isinstance(rack, Mapping):
                rect = rack.get("rect")
                if set(rack) != {"rect"} or not isinstance(rect, Sequence) or len(rect) != 4:
                    raise ValueError(f"{name}: racks[{i}] must be a vertex list or {{rect: [xmin, ymin, xmax, ymax]}}")
                rack = np.asarray(box(*rect).exterior.coords)[:-1]
            racks.append(rack)
        try:
            return cls(width=data["width"], height=data["height"], racks=tuple(racks))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name}: {exc}") from None

    @classmethod
    def from_file(cls, path: str | Path) -> WarehouseLayout:
        """Read a ``.json`` or ``.yaml``/``.yml`` layout file (YAML read with ``safe_load``)."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"layout: no file {str(path)!r}")
        text = path.read_text()
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        elif path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            raise ValueError(f"layout: {str(path)!r} must end in .json, .yaml or .yml")
        return cls.from_dict(data, name=f"layout {path.name}")


def _box_vertices(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """The (4, 2) counter-clockwise vertices of a box, in the order of shapely's ``box(...).exterior.coords[:-1]``."""
    return np.array([[x1, y0], [x1, y1], [x0, y1], [x0, y0]], dtype=np.float64)


def generate_layout(rng: np.random.Generator, ranges: LayoutRanges | None = None) -> WarehouseLayout:
    """Draw a layout of rows of racks from ``ranges`` with ``rng`` (see the module docstring)."""
    r = LayoutRanges() if ranges is None else ranges
    rows = int(rng.integers(r.rows[0], r.rows[1] + 1))
    segments = int(rng.integers(r.segments[0], r.segments[1] + 1))
    length, depth, aisle, cross = (float(rng.uniform(*getattr(r, k)))
                                   for k in ("rack_length", "rack_depth", "aisle_width", "cross_aisle_width"))
    return layout_from_sizes(rows, segments, length, depth, aisle, cross)


def layout_from_sizes(rows: int, segments: int, rack_length: float, rack_depth: float, aisle_width: float,
                      cross_aisle_width: float) -> WarehouseLayout:
    """The regular layout of ``rows`` x ``segments`` racks with these sizes [m] (the hall fits around them)."""
    width = 2 * cross_aisle_width + segments * rack_length + (segments - 1) * cross_aisle_width
    height = (rows + 1) * aisle_width + rows * rack_depth
    racks = []
    for row in range(rows):
        y0 = -height / 2 + aisle_width + row * (rack_depth + aisle_width)
        for seg in range(segments):
            x0 = -width / 2 + cross_aisle_width + seg * (rack_length + cross_aisle_width)
            racks.append(_box_vertices(x0, y0, x0 + rack_length, y0 + rack_depth))
    return WarehouseLayout(width=width, height=height, racks=tuple(racks))


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, k=1)``, remembered (a roadmap of n nodes is built every episode)."""
    return np.triu_indices(n, k=1)


class Roadmap:
    """Shortest routes through the free space of a disc of radius ``clearance``: a visibility graph (``networkx``).

    The nodes are the corners of the free space shrunk by ``clearance`` (racks grown with square, mitred
    corners, so every corner is a point the disc can reach); two corners are joined when the straight segment
    between them stays in that free space (a segment along its boundary counts as inside), weighted by its
    length. A route adds the start and the goal to the graph, joined to the corners they see, and takes the A*
    path: the shortest polygonal path around the obstacles. A start or goal outside the shrunk free space (a
    picker pressed against a rack) is joined to its nearest corner, from which the route goes on as from a start.

    When the racks are boxes whose grown copies stay apart and off the walls (every generated layout), the free
    space is the shrunk hall minus the grown boxes (shapely's own mitred buffers of the racks: the coordinates of
    the buffered free space's corners), and the roadmap is built and queried without it
    (:mod:`~sb3_crowdnav.sim.warehouse.boxes`). The graph then keeps only what a shortest path can use: the
    racks' corners (a shortest path never bends at a corner of the hall) and the edges that pass each of their
    ends on the outside of its rack (bitangents; a route's end is joined likewise): the same shortest routes, from
    a graph of about a third of the edges. Otherwise every test is a shapely predicate on :attr:`free`.
    """

    def __init__(self, layout: WarehouseLayout, clearance: float) -> None:
        check_number("clearance", clearance, allow_zero=True)
        self.layout, self.clearance = layout, float(clearance)
        w, h, c = layout.width / 2, layout.height / 2, self.clearance
        self._hall = (-w + c, -h + c, w - c, h - c)  # the free space's outline (shapely's mitred buffer gives these)
        self.grown = self._grown_racks()  # (B, 4) bounds of the racks grown by the clearance, or None (see above)
        self._joins_of: dict[tuple[float, float], tuple[list[int], list[float]]] = {}
        if self.grown is not None:
            x0, y0, x1, y1 = self._hall
            g = self.grown
            racks = np.stack([g[:, [0, 1]], g[:, [2, 1]], g[:, [2, 3]], g[:, [0, 3]]], axis=1).reshape(-1, 2)
            self.corners = np.concatenate([[(x0, y0), (x0, y1), (x1, y1), (x1, y0)], racks])
            # a segment leaving a rack's corner along (dx, dy) passes it on the outside when side * dx * dy <= 0
            self._sides = np.concatenate([np.zeros(4), np.tile([1.0, -1.0, 1.0, -1.0], len(g))])
            self._nodes = np.arange(4, len(self.corners))
            self._open = self.grown + np.array([1e-6, 1e-6, -1e-6, -1e-6])  # touching a grown rack is allowed
            self._open_list, self._grown_list = self._open.tolist(), self.grown.tolist()
            self._node_list, self._side_list = self.corners[4:].tolist(), self._sides[4:].tolist()
        else:
            self._cover = self.free.buffer(1e-6)  # segments along the boundary count as inside
            shapely.prepare(self._cover)
            rings = [ring for poly in getattr(self.free, "geoms", [self.free]) if not poly.is_empty
                     for ring in (poly.exterior, *poly.interiors)]
            self.corners = np.concatenate([np.asarray(r.coords)[:-1] for r in rings]) if rings else np.zeros((0, 2))
            self._nodes = np.arange(len(self.corners))
        self.graph = nx.Graph()
        self.graph.add_nodes_from(self._nodes.tolist())
        i, j = (self._nodes[k] for k in _pairs(len(self._nodes)))
        a, b = self.corners[i], self.corners[j]
        keep = self._outside(i, b - a) & self._outside(j, a - b)
        i, j, a, b = i[keep], j[keep], a[keep], b[keep]
        visible = self._visible(a, b)
        lengths = np.linalg.norm(a - b, axis=1)
        self.graph.add_weighted_edges_from(zip(i[visible].tolist(), j[visible].tolist(), lengths[visible].tolist(),
                                               strict=True))

    def _outside(self, corners: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """(n,) bool: a segment leaving corner ``corners[k]`` along ``direction[k]`` passes it on the outside of its
        rack (both sides of the rack at the corner on one side of the segment), as each segment of a shortest route
        does at a corner it bends around; always True without boxes."""
        if self.grown is None:
            return np.ones(len(corners), dtype=bool)
        return self._sides[corners] * direction[:, 0] * direction[:, 1] <= 0

    def _grown_racks(self) -> np.ndarray | None:
        """(B, 4) bounds of the racks grown by the clearance (mitred), when they are boxes, apart and off the walls."""
        boxes = self.layout.boxes
        if boxes is None or not len(boxes):
            return None
        racks = shapely.polygons(np.stack(self.layout.racks))
        grown = shapely.bounds(shapely.buffer(racks, self.clearance, join_style="mitre"))
        return grown if separated(grown, self._hall) else None

    @functools.cached_property
    def free(self) -> Any:
        """The free space of the disc (shapely, prepared; with boxes for racks built only when asked for)."""
        free = self.layout.free_space(self.clearance, join_style="mitre")
        shapely.prepare(free)
        return free

    def _visible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) bool: the segments a[k]-b[k] lie in the free space."""
        if not len(a):
            return np.zeros(0, dtype=bool)
        if self.grown is None:
            return shapely.covers(self._cover, shapely.linestrings(np.stack([a, b], axis=1)))
        x0, y0, x1, y1 = self._hall
        lo, hi = np.array([x0 - 1e-6, y0 - 1e-6]), np.array([x1 + 1e-6, y1 + 1e-6])
        in_hall = ((a >= lo) & (a <= hi) & (b >= lo) & (b <= hi)).all(axis=1)  # the hall is convex
        return in_hall & segments_miss_boxes(a, b, self._open)

    def is_free(self, point: Sequence[float]) -> bool:
        """Whether a disc of radius ``clearance`` centred at ``point`` is in the free space."""
        if self.grown is None:
            return bool(self.free.contains(Point(point)))
        (x, y), (x0, y0, x1, y1) = point, self._hall
        return bool(x0 < x < x1 and y0 < y < y1 and not any(gx0 <= x <= gx1 and gy0 <= y <= gy1
                                                            for gx0, gy0, gx1, gy1 in self._grown_list))

    def sample_free(self, rng: np.random.Generator) -> np.ndarray:
        """A point drawn uniformly from the free space (rejection sampling in the hall)."""
        w, h = self.layout.width / 2, self.layout.height / 2
        for _ in range(10_000):
            point = rng.uniform((-w, -h), (w, h))
            if self.is_free(point):
                return point
        raise ValueError("the free space is empty for this clearance")

    def _visible_one(self, a: np.ndarray, b: np.ndarray) -> bool:
        """:meth:`_visible` of the one segment ``a``-``b`` (in floats when the racks are boxes)."""
        if self.grown is None:
            return bool(self._visible(a[None], b[None])[0])
        (ax, ay), (bx, by), (x0, y0, x1, y1) = a.tolist(), b.tolist(), self._hall
        inside = x0 - 1e-6 <= min(ax, bx) and max(ax, bx) <= x1 + 1e-6 and y0 - 1e-6 <= min(ay, by) and \
            max(ay, by) <= y1 + 1e-6
        return inside and self._misses_racks(ax, ay, bx, by)

    def _misses_racks(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """Whether the segment enters none of the grown racks (floats; racks beside its bounding box skipped)."""
        sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
        return not any(box[0] < sx1 and sx0 < box[2] and box[1] < sy1 and sy0 < box[3] and
                       segment_meets_box(ax, ay, bx - ax, by - ay, box, interior=True) for box in self._open_list)

    def _joins(self, point: np.ndarray) -> tuple[list[int], list[float]]:
        """The graph's corners a route's end at ``point`` sees (and passes on the outside) and the edges' lengths;
        none when ``point`` is outside the free space. Remembered per point (pick slots and goals recur)."""
        key = (float(point[0]), float(point[1]))
        joins = self._joins_of.get(key)
        if joins is None and self.grown is None:
            nodes = self._nodes[self._visible(np.broadcast_to(point, self.corners.shape), self.corners)]
            joins = (nodes.tolist(), np.linalg.norm(self.corners[nodes] - point, axis=1).tolist())
        elif joins is None:  # in floats: a dozen corners against a handful of racks
            (px, py), (x0, y0, x1, y1), joins = key, self._hall, ([], [])
            if x0 - 1e-6 <= px <= x1 + 1e-6 and y0 - 1e-6 <= py <= y1 + 1e-6:
                for k, (cx, cy), side in zip(self._nodes.tolist(), self._node_list, self._side_list, strict=True):
                    dx, dy = px - cx, py - cy
                    if side * dx * dy <= 0 and self._misses_racks(px, py, cx, cy):
                        joins[0].append(k)
                        joins[1].append(math.sqrt(dx * dx + dy * dy))  # np.linalg.norm's value
        if len(self._joins_of) >= 4096:  # a fixed layout's roadmap lives for many episodes
            self._joins_of.clear()
        self._joins_of[key] = joins
        return joins

    def route(self, start: Sequence[float], goal: Sequence[float]) -> np.ndarray:
        """Waypoints (n, 2) from ``start`` to ``goal`` (both included) through the free space; ``ValueError`` when
        no route exists."""
        start, goal = np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
        if self._visible_one(start, goal):
            return np.stack([start, goal])
        (from_start, start_lengths), (to_goal, goal_lengths) = self._joins(start), self._joins(goal)
        if len(self.corners) and not (from_start and to_goal):  # an end outside the free space: via its nearest corner
            if not from_start:
                nearest = self.corners[np.argmin(np.linalg.norm(self.corners - start, axis=1))]
                return np.concatenate([start[None], self.route(nearest, goal)])
            nearest = self.corners[np.argmin(np.linalg.norm(self.corners - goal, axis=1))]
            return np.stack([start, goal]) if (nearest == start).all() else \
                np.concatenate([self.route(start, nearest), goal[None]])
        graph, n = self.graph, len(self.corners)
        points = np.concatenate([self.corners, start[None], goal[None]])
        remaining = np.linalg.norm(points - goal, axis=1).tolist()  # the A* heuristic of every node
        try:
            graph.add_weighted_edges_from(zip([n] * len(from_start), from_start, start_lengths, strict=True))
            graph.add_weighted_edges_from(zip([n + 1] * len(to_goal), to_goal, goal_lengths, strict=True))
            path = nx.astar_path(graph, n, n + 1, heuristic=lambda u, _: remaining[u])
        except (nx.NetworkXNoPath, nx.NodeNotFound):
            raise ValueError(f"no route from {tuple(start)} to {tuple(goal)} in the free space") from None
        finally:
            graph.remove_nodes_from((n, n + 1))
        return points[path]

    @staticmethod
    def route_length(route: np.ndarray) -> float:
        return float(np.sum(np.linalg.norm(np.diff(route, axis=0), axis=1)))


__all__ = ["LayoutRanges", "Roadmap", "WarehouseLayout", "generate_layout", "layout_from_sizes"]
