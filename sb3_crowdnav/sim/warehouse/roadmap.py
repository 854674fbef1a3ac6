"""The roadmap of a layout: shortest routes through the free space of a disc, on a visibility graph (``networkx``)."""

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


class _BuiltGraph(nx.Graph):
    """An undirected ``networkx`` graph handed its node and adjacency dicts built (the ``node_dict_factory`` and
    ``adjlist_outer_dict_factory`` hooks networkx documents for subclasses), without the per-edge work of its methods:
    a visibility graph of a few dozen corners is built every episode, and a route adds its two ends to it.

    :meth:`from_edges` gives the dicts ``add_nodes_from(nodes)`` then ``add_weighted_edges_from(zip(i, j, weights))``
    give (each node's neighbours in the order of the edges, the two directions of an edge sharing one attribute
    dict), and :meth:`with_ends` the graph a route's A* searches, this one unchanged.
    """

    def __init__(self, node_dict: dict | None = None, adjacency: dict | None = None) -> None:
        self.built_nodes = {} if node_dict is None else node_dict  # the very dicts networkx's factories hand it
        self.built_adjacency = {} if adjacency is None else adjacency
        self.node_dict_factory = lambda: self.built_nodes
        self.adjlist_outer_dict_factory = lambda: self.built_adjacency
        super().__init__()

    @classmethod
    def from_edges(cls, nodes: list, i: list, j: list, weights: list) -> _BuiltGraph:
        node_dict = {n: {} for n in nodes}
        adjacency: dict = {n: {} for n in node_dict}
        for u, v, w in zip(i, j, weights, strict=True):
            adjacency[u][v] = adjacency[v][u] = {"weight": w}
        return cls(node_dict, adjacency)

    def with_ends(self, start: int, start_joins: list, start_lengths: list, goal_joins: list,
                  goal_lengths: list) -> _BuiltGraph:
        """The graph A* searches for a route from node ``start`` to node ``start + 1`` (the goal): this one with the
        start's row (its edges to ``start_joins``) and the goal in the rows of ``goal_joins``. A search from the start
        reads only the start's row and the rows of the corners it expands, so the edges back to the start and the
        goal's own row, which ``add_weighted_edges_from`` of the ends' edges would add too, are left out: an edge back
        to the start only queues the start again, to be skipped, so the search finds the same path (tested). This
        graph is unchanged (its rows shared, copied where the goal is added); one graph object serves every route of
        this graph (its dicts refilled: the previous route's is gone). An end without joins is not added."""
        route = self.__dict__.get("_route")
        if route is None:
            route = self.__dict__["_route"] = _BuiltGraph()
        node_dict, adjacency, base = route.built_nodes, route.built_adjacency, self.built_adjacency
        node_dict.clear()
        node_dict.update(self.built_nodes)
        adjacency.clear()
        adjacency.update(base)
        route.__networkx_cache__.clear()
        if start_joins:
            node_dict[start] = {}
            adjacency[start] = {k: {"weight": w} for k, w in zip(start_joins, start_lengths, strict=True)}
        if goal_joins:
            node_dict[start + 1], goal = {}, start + 1
            for k, w in zip(goal_joins, goal_lengths, strict=True):
                row = adjacency[k] = dict(base[k])
                row[goal] = {"weight": w}
        return route

    def __reduce__(self):  # copies and pickles as a plain graph (the factories above are per instance)
        return nx.Graph, (nx.to_dict_of_dicts(self),)


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
        i, j = np.triu_indices(len(self.nodes), k=1)
        a, b = self.corners[i], self.corners[j]
        visible = self._visible(a, b)
        lengths = np.linalg.norm((b - a)[visible], axis=1)
        return i[visible].tolist(), j[visible].tolist(), lengths.tolist()

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
    path (``networkx.astar_path``): the shortest polygonal path around the obstacles. A start or goal outside the
    shrunk free space (a picker pressed against a rack) is joined to its nearest corner, from which the route goes
    on as from a start.

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
        """The visibility graph of the corners, built when a route first needs it (a route's ends that see each other
        need none)."""
        return _BuiltGraph.from_edges(self.space.nodes.tolist(), *self.space.edges())

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
        from_start, to_goal = query.start_joins.tolist(), query.goal_joins.tolist()
        if len(self.corners) and not (from_start and to_goal):  # an end outside the free space: via its nearest corner
            if not from_start:
                nearest = self.corners[np.argmin(np.linalg.norm(self.corners - start, axis=1))].tolist()
                return [start, *self.waypoints(nearest, goal)]
            nearest = self.corners[np.argmin(np.linalg.norm(self.corners - goal, axis=1))].tolist()
            return [start, goal] if nearest == start else [*self.waypoints(start, nearest), goal]
        graph, n = self.graph, len(self.corners)
        remaining = query.heuristic.tolist()
        ended = graph.with_ends(n, from_start, query.start_lengths.tolist(), to_goal, query.goal_lengths.tolist())
        try:
            path = nx.astar_path(ended, n, n + 1, heuristic=lambda u, _: remaining[u])
        except (nx.NetworkXNoPath, nx.NodeNotFound):
            raise ValueError(f"no route from {tuple(start)} to {tuple(goal)} in the free space") from None
        points = [*self._corner_list, start, goal]
        return [[*points[k]] for k in path]  # (copies: the corners' lists stay the roadmap's)

    @staticmethod
    def route_length(route: np.ndarray | list[list[float]]) -> float:
        """The length [m] of the polyline ``route`` (n, 2)."""
        return float(np.linalg.norm(np.diff(np.asarray(route, dtype=np.float64), axis=0), axis=1).sum())


__all__ = ["PolygonSpace", "Roadmap"]
