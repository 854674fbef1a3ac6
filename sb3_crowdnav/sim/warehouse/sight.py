"""The racks as what hides pickers from the robot: the occluder of :class:`~sb3_crowdnav.sim.sensing.PeopleSensor`."""

from __future__ import annotations

import numpy as np
import shapely

from sb3_crowdnav.sim.sensing import open_frame
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.layout import WarehouseLayout

INTERIOR = 1e-9  # [m] a polygon rack's interior: shrunk by this, so that grazing a side or a corner does not block


class RackSight:
    """Lines of sight past a layout's racks (the rule of :mod:`sb3_crowdnav.sim.sensing`: three lines per disc).

    Racks that are boxes (every generated layout's) are asked of :func:`~sb3_crowdnav.sim.warehouse.kernels.discs_in_sight`;
    other racks of shapely (a line is blocked when it meets a rack shrunk by :data:`INTERIOR`).
    """

    def __init__(self, layout: WarehouseLayout) -> None:
        self.layout = layout
        self._boxes = layout.boxes
        self._racks = None
        if self._boxes is None:
            racks = shapely.union_all([shapely.Polygon(p) for p in layout.rack_vertices]).buffer(-INTERIOR,
                                                                                                  join_style="mitre")
            shapely.prepare(racks)
            self._racks = racks

    def frame(self, x: float, y: float, row: np.ndarray, present: np.ndarray,
              sensor_range: float | None) -> tuple[np.ndarray, np.ndarray]:
        """One frame of the people sensor past the racks (:class:`~sb3_crowdnav.sim.sensing.Occluder`); compiled in
        one call with boxes for racks (:func:`~sb3_crowdnav.sim.warehouse.kernels.people_frame`)."""
        if self._boxes is not None:
            states, seen = np.empty_like(row), np.empty(len(row), dtype=bool)
            kernels.people_frame(x, y, row, present, -1.0 if sensor_range is None else sensor_range, self._boxes,
                                 states, seen)
            return states, seen
        states, seen = open_frame(x, y, row, present, sensor_range)
        if seen.any():
            idx = np.flatnonzero(seen)
            seen[idx] = self.in_sight(x, y, row[idx, :2], row[idx, 4])
            states[~seen] = 0.0
        return states, seen

    def deliver(self, x: float, y: float, row: np.ndarray, present: np.ndarray, sensor_range: float | None,
                history: np.ndarray, mask: np.ndarray) -> bool:
        """:meth:`frame` delivered into the observed ``history`` and ``mask`` in one compiled call with boxes for racks
        (:func:`~sb3_crowdnav.sim.warehouse.kernels.people_deliver`; :class:`~sb3_crowdnav.sim.sensing.Occluder`);
        False for other racks."""
        if self._boxes is None:
            return False
        kernels.people_deliver(x, y, row, present, -1.0 if sensor_range is None else sensor_range, self._boxes,
                               history, mask)
        return True

    def in_sight(self, x: float, y: float, positions: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """(n,) bool: whether a line of sight from (x, y) reaches each disc past the racks."""
        if self._boxes is not None:
            return kernels.discs_in_sight(x, y, np.ascontiguousarray(positions, dtype=np.float64),
                                          np.ascontiguousarray(radii, dtype=np.float64), self._boxes)
        d = positions - np.array([x, y])
        norm = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
        side = np.stack([-d[:, 1], d[:, 0]], axis=1) / norm[:, None] * radii[:, None]
        seen = np.zeros(len(positions), dtype=bool)
        for target in (positions, positions + side, positions - side):
            lines = shapely.linestrings(np.stack([np.broadcast_to([x, y], target.shape), target], axis=1))
            seen |= ~shapely.intersects(self._racks, lines)
        return seen


__all__ = ["RackSight"]
