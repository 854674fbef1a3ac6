"""Compiled loops (``numba``) of the warehouse's geometry: the robot's sensing and swept collision every step, and the
visibility tests that build a roadmap and join a route's ends to it every reset.

Each kernel is the implementation of what it computes: a loop over arrays of a few dozen values, where the per-call
overhead of several small NumPy calls would cost more than the arithmetic. Distances between points and segments come
from :mod:`~sb3_crowdnav.sim.geometry`, compiled the same way. The readable forms the kernels are checked against,
with tolerances and properties, live in the tests (``tests/warehouse_reference.py``).

Kernels compile on their first call and are cached on disk in this package's ``__pycache__`` (``cache=True``): a new
process loads them in well under a second (where that folder is read-only, numba caches in a directory of the
user's, or in ``NUMBA_CACHE_DIR``).
"""

from sb3_crowdnav.sim.warehouse.kernels.base import (
    disc_in_sight,
    discs_in_sight,
    misses_boxes,
    people_deliver,
    people_frame,
    point_clearance,
    segment_clearance,
)
from sb3_crowdnav.sim.warehouse.kernels.pickers import (
    AfterStep,
    far_from_both,
    picker_after_step,
    picker_after_step_fields,
    picker_preferences,
    picker_progress,
    points_clearance,
    pressed,
    slot_points,
    spread,
)
from sb3_crowdnav.sim.warehouse.kernels.robot import (
    BoxRoadmap,
    RouteQuery,
    Sensing,
    SensingAndRoute,
    bitangent_edges,
    box_roadmap,
    distances_to,
    free_points,
    joins,
    route_query,
    route_query_fields,
    sense,
    sense_and_follow,
    separated,
    step_sensing,
    swept_segment_distance,
)
from sb3_crowdnav.sim.warehouse.kernels.routes import adjacency, astar_route

__all__ = [
    "AfterStep",
    "BoxRoadmap",
    "RouteQuery",
    "Sensing",
    "SensingAndRoute",
    "adjacency",
    "astar_route",
    "bitangent_edges",
    "box_roadmap",
    "disc_in_sight",
    "discs_in_sight",
    "distances_to",
    "far_from_both",
    "free_points",
    "joins",
    "misses_boxes",
    "people_deliver",
    "people_frame",
    "picker_after_step",
    "picker_after_step_fields",
    "picker_preferences",
    "picker_progress",
    "point_clearance",
    "points_clearance",
    "pressed",
    "route_query",
    "route_query_fields",
    "segment_clearance",
    "sense",
    "sense_and_follow",
    "separated",
    "slot_points",
    "spread",
    "step_sensing",
    "swept_segment_distance",
]
