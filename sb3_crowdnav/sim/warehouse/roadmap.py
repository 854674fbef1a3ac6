"""The roadmap of a layout: shortest routes through the free space of a disc, on a visibility graph (``networkx``)."""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import Point

from sb3_crowdnav.sim.validation import check_number
from sb3_crowdnav.sim.warehouse import kernels

if TYPE_CHECKING:
    from sb3_crowdnav.sim.warehouse.layout import WarehouseLayout


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, k=1)``, remembered (a roadmap of n nodes is built every episode)."""
    return np.triu_indices(n, k=1)


class _BuiltGraph(nx.Graph):
    """An undirected ``networkx`` graph handed its node and adjacency dicts built (the ``node_dict_factory`` and
    ``adjlist_outer_dict_factory`` hooks networkx documents for subclasses), without the per-edge work of its methods:
    a visibility graph of a few dozen corners is built every episode, and a route adds its two ends to it.

    :meth:`from_edges` gives the dicts ``add_nodes_from(nodes)`` then ``add_weighted_edges_from(zip(i, j, weights))``
    give (each node's neighbours in the order of the edges, the two directions of an edge sharing one attribute
    dict), and :meth:`with_ends` the graph a route's A* searches, this one unchanged.
    """

    def __init__(self, node_dict: dict | None = None, adjacency: dict | None = None) -> None:
        node_dict = {} if node_dict is None else node_dict
        adjacency = {} if adjacency is None else adjacency
        self.node_dict_factory = lambda: node_dict
        self.adjlist_outer_dict_factory = lambda: adjacency
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
        node_dict, adjacency, base = route._node, route._adj, self._adj
        node_dict.clear()
        node_dict.update(self._node)
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


class Roadmap:
    """Shortest routes through the free space of a disc of radius ``clearance``: A* on a visibility graph.

    The nodes are the corners of the free space shrunk by ``clearance`` (racks grown with square, mitred
    corners, so every corner is a point the disc can reach); two corners are joined when the straight segment
    between them stays in that free space (a segment along its boundary counts as inside), weighted by its
    length. A route adds the start and the goal to the graph, joined to the corners they see, and takes the A*
    path (``networkx.astar_path``): the shortest polygonal path around the obstacles. A start or goal outside the
    shrunk free space (a picker pressed against a rack) is joined to its nearest corner, from which the route goes
    on as from a start.

    When the racks are boxes whose grown copies stay apart and off the walls (every generated layout), the free
    space is the shrunk hall minus the boxes grown by ``clearance`` (shapely's mitred buffers of the racks, whose
    corners are the buffered free space's, to within an ulp), and the roadmap is built and queried without it
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
        self._joins_of: dict[tuple[float, float], tuple[list[int], list[float]]] = {}
        boxes, self.grown = layout.boxes, None  # grown: (B, 4) the racks grown by the clearance, or None (see above)
        if boxes is not None and len(boxes):
            # a mitred buffer of a box is the box grown by c (shapely's corners within an ulp); the corners are the
            # hall's, then each grown rack's counter-clockwise from (xmin, ymin); a segment leaving a rack's corner
            # along (dx, dy) passes it on the outside when side * dx * dy <= 0; touching a grown rack is allowed (open)
            apart, grown, self.corners, self._sides, self._open = kernels.box_roadmap(boxes, c, *self._hall)
            self.grown = grown if apart else None
        if self.grown is not None:
            self._grown_list, self._corner_list = self.grown.tolist(), self.corners.tolist()
            self._nodes = np.arange(4, len(self.corners))
        else:
            self._cover = self.free.buffer(1e-6)  # segments along the boundary count as inside
            shapely.prepare(self._cover)
            rings = [ring for poly in getattr(self.free, "geoms", [self.free]) if not poly.is_empty
                     for ring in (poly.exterior, *poly.interiors)]
            self.corners = np.concatenate([np.asarray(r.coords)[:-1] for r in rings]) if rings else np.zeros((0, 2))
            self._nodes = np.arange(len(self.corners))
            self._corner_list = self.corners.tolist()

    @functools.cached_property
    def graph(self) -> nx.Graph:
        """The visibility graph of the corners, built when a route first needs it (a route's ends that see each other
        need none)."""
        return _BuiltGraph.from_edges(self._nodes.tolist(), *self._edges())

    def _edges(self) -> tuple[list[int], list[int], list[float]]:
        """The graph's edges: both corners and the length of every pair of corners that see each other, in the order
        of ``np.triu_indices``.

        With boxes only the bitangents: a segment leaving a rack's corner along (dx, dy) passes it on the outside
        of the rack (both sides of the rack at the corner on one side of the segment, as each segment of a shortest
        route does at a corner it bends around) when side * dx * dy <= 0, at either end (the product keeps its
        sign along -(dx, dy)); and the corners are inside the hall, so the segment is in it.
        """
        if self.grown is not None:  # (kernels.bitangent_edges: the loops of this NumPy form, the same values)
            i, j, lengths = kernels.bitangent_edges(self.corners, self._sides, 4, self._open)
            return i.tolist(), j.tolist(), lengths.tolist()
        i, j = (self._nodes[k] for k in _pairs(len(self._nodes)))
        a, b = self.corners[i], self.corners[j]
        visible = self._visible(a, b)
        lengths = np.linalg.norm((b - a)[visible], axis=1)
        return i[visible].tolist(), j[visible].tolist(), lengths.tolist()

    @functools.cached_property
    def free(self) -> Any:
        """The free space of the disc (shapely, prepared; with boxes for racks built only when asked for)."""
        free = self.layout.free_space(self.clearance, join_style="mitre")
        shapely.prepare(free)
        return free

    def _visible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) bool: the segments a[k]-b[k] lie in the free space (shapely's ``covers``: racks that are not boxes;
        with boxes the kernels decide, :meth:`_edges`, :meth:`_joins`, :meth:`_visible_one`)."""
        if not len(a):
            return np.zeros(0, dtype=bool)
        return shapely.covers(self._cover, shapely.linestrings(np.stack([a, b], axis=1)))

    def free_points(self, points: np.ndarray) -> list[bool]:
        """:meth:`is_free` of each of ``points`` (n, 2) (with boxes for racks at once, :func:`kernels.free_points`)."""
        if self.grown is None:
            return [self.is_free(p) for p in points.tolist()]
        return kernels.free_points(points, self._hall, self.grown).tolist()

    def is_free(self, point: Sequence[float]) -> bool:
        """Whether a disc of radius ``clearance`` centred at ``point`` is in the free space."""
        if self.grown is None:
            return bool(self.free.contains(Point(point)))
        (x, y), (x0, y0, x1, y1) = point, self._hall
        return bool(x0 < x < x1 and y0 < y < y1 and not any(gx0 <= x <= gx1 and gy0 <= y <= gy1
                                                            for gx0, gy0, gx1, gy1 in self._grown_list))

    def _visible_one(self, a: np.ndarray, b: np.ndarray) -> bool:
        """:meth:`_visible` of the one segment ``a``-``b`` (in floats when the racks are boxes)."""
        if self.grown is None:
            return bool(self._visible(np.asarray(a, dtype=np.float64)[None], np.asarray(b, dtype=np.float64)[None])[0])
        (ax, ay), (bx, by), (x0, y0, x1, y1) = _floats(a), _floats(b), self._hall
        inside = x0 - 1e-6 <= min(ax, bx) and max(ax, bx) <= x1 + 1e-6 and y0 - 1e-6 <= min(ay, by) and \
            max(ay, by) <= y1 + 1e-6
        return inside and kernels.misses_boxes(ax, ay, bx, by, self._open)

    def _joins(self, point: np.ndarray) -> tuple[list[int], list[float]]:
        """The graph's corners a route's end at ``point`` sees (and passes on the outside) and the edges' lengths;
        none when ``point`` is outside the free space. Remembered per point (pick slots and goals recur)."""
        key = (float(point[0]), float(point[1]))
        joins = self._joins_of.get(key)
        if joins is None and self.grown is None:
            nodes = self._nodes[self._visible(np.broadcast_to(point, self.corners.shape), self.corners)]
            joins = (nodes.tolist(), np.linalg.norm(self.corners[nodes] - point, axis=1).tolist())
        elif joins is None:  # the corners it sees and passes on the outside (kernels.joins), lengths as np.linalg.norm's
            (px, py), (x0, y0, x1, y1), joins = key, self._hall, ([], [])
            if x0 - 1e-6 <= px <= x1 + 1e-6 and y0 - 1e-6 <= py <= y1 + 1e-6:
                nodes, lengths = kernels.joins(px, py, self.corners, self._sides, 4, self._open)
                joins = (nodes.tolist(), lengths.tolist())
        if len(self._joins_of) >= 4096:  # a fixed layout's roadmap lives for many episodes
            self._joins_of.clear()
        self._joins_of[key] = joins
        return joins

    def route(self, start: Sequence[float], goal: Sequence[float]) -> np.ndarray:
        """Waypoints (n, 2) from ``start`` to ``goal`` (both included) through the free space; ``ValueError`` when
        no route exists."""
        return np.array(self.waypoints(start, goal), dtype=np.float64).reshape(-1, 2)

    def waypoints(self, start: Sequence[float], goal: Sequence[float]) -> list[list[float]]:
        """:meth:`route` as a list of ``[x, y]`` floats (the same values)."""
        start, goal = [float(start[0]), float(start[1])], [float(goal[0]), float(goal[1])]
        remaining = None
        if self.grown is not None:  # the sight test, both ends' joins and the heuristic in one kernel call
            (sx, sy), (gx, gy) = start, goal
            query = kernels.route_query(sx, sy, gx, gy, self.corners, self._sides, 4, self._open, self._hall).tolist()
            if query[0]:
                return [start, goal]
            a, b = int(query[1]), int(query[2])
            from_start, to_goal = [int(k) for k in query[3 : 3 + a]], [int(k) for k in query[3 + a : 3 + a + b]]
            start_lengths, goal_lengths = query[3 + a + b : 3 + 2 * a + b], query[3 + 2 * a + b : 3 + 2 * (a + b)]
            remaining = query[3 + 2 * (a + b) :]
        elif self._visible_one(start, goal):
            return [start, goal]
        else:
            (from_start, start_lengths), (to_goal, goal_lengths) = self._joins(start), self._joins(goal)
        if len(self.corners) and not (from_start and to_goal):  # an end outside the free space: via its nearest corner
            if not from_start:
                nearest = self.corners[np.argmin(np.linalg.norm(self.corners - start, axis=1))].tolist()
                return [start, *self.waypoints(nearest, goal)]
            nearest = self.corners[np.argmin(np.linalg.norm(self.corners - goal, axis=1))].tolist()
            return [start, goal] if nearest == start else [*self.waypoints(start, nearest), goal]
        graph, n = self.graph, len(self.corners)
        points = [*self._corner_list, start, goal]
        if remaining is None:  # the A* heuristic of every node (np.linalg.norm's operations)
            (sx, sy), (gx, gy) = start, goal
            remaining = kernels.distances_to(self.corners, gx, gy).tolist()
            remaining += (math.sqrt((sx - gx) * (sx - gx) + (sy - gy) * (sy - gy)), 0.0)
        try:  # (the graph with the ends added: what add_weighted_edges_from would make of it, the graph kept)
            path = nx.astar_path(graph.with_ends(n, from_start, start_lengths, to_goal, goal_lengths), n, n + 1,
                                 heuristic=lambda u, _: remaining[u])
        except (nx.NetworkXNoPath, nx.NodeNotFound):
            raise ValueError(f"no route from {tuple(start)} to {tuple(goal)} in the free space") from None
        return [[*points[k]] for k in path]  # (copies: the corners' lists stay the roadmap's)

    @staticmethod
    def route_length(route: np.ndarray | list[list[float]]) -> float:
        """The length [m] of the polyline ``route`` (n, 2): ``np.sum`` of ``np.linalg.norm`` of ``np.diff``; in floats
        below 8 segments (NumPy adds fewer than 8 values one after the other, from 0; more pairwise)."""
        if len(route) > 8:
            return float(np.sum(np.linalg.norm(np.diff(np.asarray(route, dtype=np.float64), axis=0), axis=1)))
        points = route.tolist() if isinstance(route, np.ndarray) else route
        total = 0.0
        for (x0, y0), (x1, y1) in itertools.pairwise(points):
            dx, dy = x1 - x0, y1 - y0
            total += math.sqrt(dx * dx + dy * dy)
        return total


def _floats(point: Sequence[float]) -> list[float]:
    return point.tolist() if isinstance(point, np.ndarray) else point


__all__ = ["Roadmap"]
