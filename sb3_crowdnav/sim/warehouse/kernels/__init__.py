"""Compiled loops (``numba``) of the warehouse's geometry: the robot's sensing and swept collision every step, and the
visibility tests that build a roadmap and join a route's ends to it every reset.

Each kernel is the loop form of a NumPy or Python-float function of the package and gives its values exactly (the same
IEEE operations in the same order: no fast-math, divisions by zero giving inf/NaN as NumPy's do; ``math.hypot`` and
``math.sqrt`` are the C library's, as NumPy's). A kernel stands in for several small NumPy calls on arrays of a few
dozen values, whose per-call overhead costs more than the arithmetic. The tests compare each kernel with the function
it replaces (``tests/test_warehouse_kernels.py``).

Where the replaced code calls CPython's ``math.hypot`` or ``math.dist`` (correctly rounded in most cases, unlike the
C library's ``hypot``), the kernel calls :func:`py_hypot`, CPython 3.11's algorithm for two values, so that the kernel
gives the same values on the Python the package is tested with.

Kernels compile on their first call and are cached on disk in this package's ``__pycache__`` (``cache=True``): a new
process loads them in well under a second (where that folder is read-only, numba caches in a directory of the
user's, or in ``NUMBA_CACHE_DIR``). The first compilation takes about 8 s.
"""

from sb3_crowdnav.sim.warehouse.kernels.base import (
    misses_boxes,
    point_clearance,
    py_hypot,
    segment_clearance,
    segment_distance,
)
from sb3_crowdnav.sim.warehouse.kernels.pickers import (
    far_from_both,
    picker_after_step,
    picker_preferences,
    picker_progress,
    points_clearance,
    pressed,
    slot_points,
    spread,
)
from sb3_crowdnav.sim.warehouse.kernels.robot import (
    bitangent_edges,
    box_roadmap,
    distances_to,
    free_points,
    joins,
    route_query,
    segment_geometry,
    sense,
    sense_and_follow,
    separated,
)

__all__ = [
    "bitangent_edges",
    "box_roadmap",
    "distances_to",
    "far_from_both",
    "free_points",
    "joins",
    "misses_boxes",
    "picker_after_step",
    "picker_preferences",
    "picker_progress",
    "point_clearance",
    "points_clearance",
    "pressed",
    "py_hypot",
    "route_query",
    "segment_clearance",
    "segment_distance",
    "segment_geometry",
    "sense",
    "sense_and_follow",
    "separated",
    "slot_points",
    "spread",
]
