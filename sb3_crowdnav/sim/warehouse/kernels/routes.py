"""The route search of a roadmap: ``networkx.astar_path``'s algorithm, compiled, on the roadmap's adjacency arrays.

A warehouse reset plans half a dozen routes on two fresh roadmaps of a few dozen corners, where networkx's per-call
work (building the graph's dicts, adding the route's ends, a Python loop per expanded corner) cost a third of the
reset. This kernel runs the same search: the same priority queue of ``(f, counter, node, cost, parent)`` tuples, the
neighbours in the graph's insertion order, the same skips of explored and re-enqueued nodes and the same sums, so it
returns the path networkx returns on the same graph, ties included (``tests/test_warehouse_kernels.py`` compares the
two on generated layouts and random graphs).
"""

from __future__ import annotations

import heapq

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT


@njit(**JIT)
def adjacency(nodes, i, j, lengths):  # pragma: no cover  (compiled)
    """The undirected graph of the edges ``i[e]``-``j[e]`` (E,) of ``lengths`` (E,) on nodes ``0 .. nodes - 1`` as
    compressed rows ``(indptr (nodes + 1,), neighbours (2E,), lengths (2E,))``: each node's neighbours in the order of
    its edges (the order ``networkx.Graph.add_weighted_edges_from`` keeps in its adjacency dicts)."""
    indptr = np.zeros(nodes + 1, np.int64)
    for e in range(i.shape[0]):
        indptr[i[e] + 1] += 1
        indptr[j[e] + 1] += 1
    for k in range(nodes):
        indptr[k + 1] += indptr[k]
    filled = indptr[:-1].copy()
    neighbours, weights = np.empty(indptr[nodes], np.int64), np.empty(indptr[nodes])
    for e in range(i.shape[0]):
        for a, b in ((i[e], j[e]), (j[e], i[e])):
            neighbours[filled[a]], weights[filled[a]] = b, lengths[e]
            filled[a] += 1
    return indptr, neighbours, weights


@njit(**JIT)
def astar_route(indptr, neighbours, lengths, start_joins, start_lengths, goal_joins, goal_lengths,
                heuristic):  # pragma: no cover  (compiled)
    """The A* path from the start (node n) to the goal (node n + 1) over the corners ``0 .. n - 1`` of the graph in
    compressed rows (:func:`adjacency`, n = ``len(indptr) - 1``), the start joined to ``start_joins`` and the goal to
    ``goal_joins`` with their lengths (the goal last in each of its corners' rows), ``heuristic`` (n + 2,) the
    estimate of each node's distance to the goal.

    :return: the path's nodes, start to goal; empty when there is none (an end without joins, or no way through)
    """
    n = indptr.shape[0] - 1
    start, goal = n, n + 1
    if start_joins.shape[0] == 0 or goal_joins.shape[0] == 0:
        return np.empty(0, np.int64)
    to_goal = np.full(n, np.nan)  # the goal's edge from each corner it joins (NaN: none)
    for k in range(goal_joins.shape[0]):
        to_goal[goal_joins[k]] = goal_lengths[k]
    enqueued = np.zeros(n + 2, np.bool_)
    queued_cost = np.zeros(n + 2)
    explored = np.zeros(n + 2, np.bool_)
    parent_of = np.full(n + 2, -1, np.int64)
    queue = [(0.0, 0, start, 0.0, -1)]
    counter = 1
    while len(queue):
        _, _, node, cost, parent = heapq.heappop(queue)
        if node == goal:
            path = [node]
            while parent != -1:
                path.append(parent)
                parent = parent_of[parent]
            out = np.empty(len(path), np.int64)
            for k in range(len(path)):
                out[k] = path[len(path) - 1 - k]
            return out
        if explored[node]:
            if parent_of[node] == -1:  # the start, never re-parented
                continue
            if queued_cost[node] < cost:  # a better path was enqueued after this one
                continue
        explored[node] = True
        parent_of[node] = parent
        if node == start:
            first, last = 0, start_joins.shape[0]
        else:
            first, last = indptr[node], indptr[node + 1]
        extra = 0 if node == start or np.isnan(to_goal[node]) else 1
        for k in range(first, last + extra):
            if k == last:
                neighbour, edge = goal, to_goal[node]
            elif node == start:
                neighbour, edge = start_joins[k], start_lengths[k]
            else:
                neighbour, edge = neighbours[k], lengths[k]
            new_cost = cost + edge
            if enqueued[neighbour] and queued_cost[neighbour] <= new_cost:
                continue
            enqueued[neighbour], queued_cost[neighbour] = True, new_cost
            heapq.heappush(queue, (new_cost + heuristic[neighbour], counter, neighbour, new_cost, node))
            counter += 1
    return np.empty(0, np.int64)
