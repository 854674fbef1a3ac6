"""The roadmap of a layout: shortest routes through the free space of a disc, by A* on a visibility graph."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, Protocol

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import Point

from sb3_crowdnav.sim.validation import check_number
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.boxes import BoxSpace


class RackLayout(Protocol):
    """What a roadmap reads of its layout (a :class:`~sb3_crowdnav.sim.warehouse.layout.WarehouseLayout`, which
    builds its roadmaps: typed by what is read, so that the two modules do not import each other)."""

    width: float  # [m]
    height: float  # [m]

    @property
    def boxes(self) -> np.ndarray | None: ...

    def free_space(self, clearance: float = 0.0, join_style: str = "round") -> Any: ...


class PolygonSpace:
    """The free space of a disc among racks of any shape: shapely's ``free`` polygon (buffered by 1 µm for the
    visibility tests, so that a segment along its boundary counts as inside) and its corners. Asked through the same
    methods as :class:`~sb3_crowdnav.sim.warehouse.boxes.BoxSpace`."""

    def __init__(self, free: Any) -> None:
        self.free = free
        self._cover = free.buffer(1e-6)
        shapely.prepare(self._cover)
        rings = [ring for poly in getattr(free, "geoms", [free]) if not poly.is_empty
                 for ring in (poly.exterior, *poly.interiors)]
        self.corners = np.concatenate([np.asarray(r.coords)[:-1] for r in rings]) if rings else np.zeros((0, 2))
        self.nodes = np.arange(len(self.corners))
        self._joins_of: dict[tuple[float, float], tuple[list[int], list[float]]] = {}

    def _visible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) bool: the segments a[k]-b[k] (n, 2) lie in the free space."""
        if not len(a):
            return np.zeros(0, dtype=bool)
        return shapely.covers(self._cover, shapely.linestrings(np.stack([a, b], axis=1)))

    def edges(self) -> tuple[list[int], list[int], list[float]]:
        """Both corners and the length of every pair of corners that see each other, in the order of
        ``np.triu_indices``."""
        i, j, lengths = self.edge_arrays()
        return i.tolist(), j.tolist(), lengths.tolist()

    def edge_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`edges` as arrays: i (E,) and j (E,) int64, the lengths (E,)."""
        i, j = np.triu_indices(len(self.nodes), k=1)
        a, b = self.corners[i], self.corners[j]
        visible = self._visible(a, b)
        lengths = np.linalg.norm((b - a)[visible], axis=1)
        return i[visible].astype(np.int64), j[visible].astype(np.int64), lengths

    def free_points(self, points: np.ndarray) -> list[bool]:
        """:meth:`is_free` of each of ``points`` (n, 2)."""
        return [self.is_free(p) for p in points.tolist()]

    def is_free(self, point: Sequence[float]) -> bool:
        """Whether the disc centred at ``point`` is in the free space."""
        return bool(self.free.contains(Point(point)))

    def sees(self, a: Sequence[float], b: Sequence[float]) -> bool:
        """Whether the segment ``a``-``b`` lies in the free space."""
        return bool(self._visible(np.asarray(a, dtype=np.float64)[None], np.asarray(b, dtype=np.float64)[None])[0])

    def joins(self, point: Sequence[float]) -> tuple[list[int], list[float]]:
        """The corners a route's end at ``point`` sees and their distances; none when ``point`` is outside the free
        space. Remembered per point (pick slots and goals recur)."""
        key = (float(point[0]), float(point[1]))
        joins = self._joins_of.get(key)
        if joins is None:
            nodes = self.nodes[self._visible(np.broadcast_to(key, self.corners.shape), self.corners)]
            joins = (nodes.tolist(), np.linalg.norm(self.corners[nodes] - key, axis=1).tolist())
            if len(self._joins_of) >= 4096:  # a fixed layout's roadmap lives for many episodes
                self._joins_of.clear()
            self._joins_of[key] = joins
        return joins

    def query(self, start: Sequence[float], goal: Sequence[float]) -> kernels.RouteQuery:
        """What a route from ``start`` to ``goal`` asks before its search."""
        if self.sees(start, goal):
            none, empty = np.zeros(0, dtype=np.int64), np.zeros(0)
            return kernels.RouteQuery(True, none, none, empty, empty, empty)
        (start_joins, start_lengths), (goal_joins, goal_lengths) = self.joins(start), self.joins(goal)
        points = np.concatenate([self.corners, [start, goal]])
        return kernels.RouteQuery(False, np.array(start_joins, dtype=np.int64), np.array(goal_joins, dtype=np.int64),
                                  np.array(start_lengths), np.array(goal_lengths),
                                  np.linalg.norm(points - np.asarray(goal), axis=1))


class Roadmap:
    """Shortest routes through the free space of a disc of radius ``clearance``: A* on a visibility graph.

    The nodes are the corners of the free space shrunk by ``clearance`` (racks grown with square, mitred
    corners, so every corner is a point the disc can reach); two corners are joined when the straight segment
    between them stays in that free space (a segment along its boundary counts as inside), weighted by its
    length. A route adds the start and the goal to the graph, joined to the corners they see, and takes the A*
    path (:func:`~sb3_crowdnav.sim.warehouse.kernels.astar_route`: ``networkx.astar_path``'s search, compiled, with
    the straight distance to the goal as the heuristic): the shortest polygonal path around the obstacles. A start or
    goal outside the shrunk free space (a picker pressed against a rack) is joined to its nearest corner, from which the
    route goes on as from a start.

    The free space is chosen once, in the constructor, as :attr:`space`: a
    :class:`~sb3_crowdnav.sim.warehouse.boxes.BoxSpace` when the racks are boxes whose grown copies stay apart and
    off the walls (every generated layout; a few comparisons per question, and only the bitangent edges), else a
    :class:`PolygonSpace` (shapely's predicates on :attr:`free`).
    """

    def __init__(self, layout: RackLayout, clearance: float) -> None:
        check_number("clearance", clearance, allow_zero=True)
        self.layout, self.clearance = layout, float(clearance)
        w, h, c = layout.width / 2, layout.height / 2, self.clearance
        hall = (-w + c, -h + c, w - c, h - c)  # the free space's outline (shapely's mitred buffer gives these)
        boxes = layout.boxes
        geometry = kernels.box_roadmap(boxes, c, *hall) if boxes is not None and len(boxes) else None
        self.space: BoxSpace | PolygonSpace = BoxSpace(hall, geometry) if geometry is not None and geometry.apart \
            else PolygonSpace(self.free)
        self.corners = self.space.corners
        self._corner_list = self.corners.tolist()

    @functools.cached_property
    def graph(self) -> nx.Graph:
        """The visibility graph of the corners as a ``networkx`` graph, edges weighted by their lengths (for a look at
        it; the routes search :attr:`adjacency`, the same graph)."""
        graph = nx.Graph()
        graph.add_nodes_from(self.space.nodes.tolist())
        graph.add_weighted_edges_from(zip(*self.space.edges(), strict=True))
        return graph

    @functools.cached_property
    def adjacency(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The visibility graph as compressed rows (:func:`~sb3_crowdnav.sim.warehouse.kernels.adjacency`), built
        when a route first needs it (a route's ends that see each other need none)."""
        return kernels.adjacency(len(self.corners), *self.space.edge_arrays())

    @functools.cached_property
    def free(self) -> Any:
        """The free space of the disc (shapely, prepared; with boxes for racks built only when asked for)."""
        free = self.layout.free_space(self.clearance, join_style="mitre")
        shapely.prepare(free)
        return free

    def free_points(self, points: np.ndarray) -> list[bool]:
        """:meth:`is_free` of each of ``points`` (n, 2)."""
        return self.space.free_points(points)

    def is_free(self, point: Sequence[float]) -> bool:
        """Whether a disc of radius ``clearance`` centred at ``point`` is in the free space."""
        return self.space.is_free(point)

    def route(self, start: Sequence[float], goal: Sequence[float]) -> np.ndarray:
        """Waypoints (n, 2) from ``start`` to ``goal`` (both included) through the free space; ``ValueError`` when
        no route exists."""
        return np.array(self.waypoints(start, goal), dtype=np.float64).reshape(-1, 2)

    def waypoints(self, start: Sequence[float], goal: Sequence[float]) -> list[list[float]]:
        """:meth:`route` as a list of ``[x, y]`` floats (the same values)."""
        start, goal = [float(start[0]), float(start[1])], [float(goal[0]), float(goal[1])]
        query = self.space.query(start, goal)
        if query.direct:
            return [start, goal]
        from_start, to_goal = query.start_joins.shape[0], query.goal_joins.shape[0]
        if len(self.corners) and not (from_start and to_goal):  # an end outside the free space: via its nearest corner
            if not from_start:
                nearest = self.corners[np.argmin(np.linalg.norm(self.corners - start, axis=1))].tolist()
                return [start, *self.waypoints(nearest, goal)]
            nearest = self.corners[np.argmin(np.linalg.norm(self.corners - goal, axis=1))].tolist()
            return [start, goal] if nearest == start else [*self.waypoints(start, nearest), goal]
        path = kernels.astar_route(*self.adjacency, query.start_joins, query.start_lengths, query.goal_joins,
                                   query.goal_lengths, query.heuristic).tolist()
        if not path:
            raise ValueError(f"no route from {tuple(start)} to {tuple(goal)} in the free space")
        corners, ends = self._corner_list, (start, goal)  # the nodes: the corners, then the start and the goal
        n = len(corners)
        return [[*(corners[k] if k < n else ends[k - n])] for k in path]  # (copies: the corners' lists stay the roadmap's)

    @staticmethod
    def route_length(route: np.ndarray | list[list[float]]) -> float:
        """The length [m] of the polyline ``route`` (n, 2): ``norm(diff(route), axis=1).sum()`` as the ufuncs those
        call (``diff`` subtracts the shifted views, ``norm`` is ``sqrt(add.reduce(d * d))`` of a real array), without
        their Python layers (every reset asks it of the robot's route): the same values."""
        points = np.asarray(route, dtype=np.float64)
        d = points[1:] - points[:-1]
        return float(np.sqrt(np.add.reduce(d * d, axis=1)).sum())


__all__ = ["PolygonSpace", "Roadmap"]
