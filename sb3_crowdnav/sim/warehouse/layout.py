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

Geometry is `shapely`'s (with the fast paths of :mod:`~sb3_crowdnav.sim.warehouse.boxes` for box racks); routes are
shortest paths on a visibility roadmap of the free space (`networkx`, :mod:`~sb3_crowdnav.sim.warehouse.roadmap`).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon, box

from sb3_crowdnav.sim.draws import uniform
from sb3_crowdnav.sim.geometry import polygon_segments
from sb3_crowdnav.sim.validation import check_instance, check_int, check_number
from sb3_crowdnav.sim.warehouse.boxes import rack_boxes
from sb3_crowdnav.sim.warehouse.roadmap import Roadmap  # re-exported: the roadmap of a layout


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

    @functools.cached_property
    def _size_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The low and high bounds (4,) [m] of the rack length, rack depth, aisle and cross aisle widths that
        :func:`generate_layout` draws from: built once per ranges (a layout is drawn at every reset; the same values
        as building them each time)."""
        bounds = np.array([self.rack_length, self.rack_depth, self.aisle_width, self.cross_aisle_width])
        low, high = np.ascontiguousarray(bounds[:, 0]), np.ascontiguousarray(bounds[:, 1])
        low.setflags(write=False)
        high.setflags(write=False)
        return low, high


def _pair(name: str, value: Any) -> tuple[Any, Any]:
    check_instance(name, value, (tuple, list), "a (min, max) pair")
    if len(value) != 2:
        raise ValueError(f"{name} must be a (min, max) pair, got {value!r}")
    return value[0], value[1]


@dataclass(frozen=True)
class WarehouseLayout:
    """A walled hall and its racks (static obstacles), in world metres.

    :param width: hall size along x [m]
    :param height: hall size along y [m]
    :param racks: rack polygons, each a (k, 2) sequence of vertices (k >= 3), inside the hall (or one (B, k, 2)
        float array of them: checked at once)
    """

    width: float
    height: float
    racks: tuple[np.ndarray, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        check_number("width", self.width)
        check_number("height", self.height)
        if isinstance(self.racks, np.ndarray) and self.racks.dtype == np.float64 and self.racks.ndim == 3 and \
                self.racks.shape[1] >= 3 and self.racks.shape[2] == 2 and np.isfinite(self.racks).all():
            # racks of as many vertices each in one array (layout_from_sizes'): the same checks at once
            vertices = np.array(self.racks)
            vertices.setflags(write=False)
            object.__setattr__(self, "racks", tuple(vertices))  # read-only views
            return
        racks = []
        for i, rack in enumerate(self.racks):
            vertices = np.asarray(rack, dtype=np.float64)
            if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3:
                raise ValueError(f"racks[{i}] must be a (k, 2) array of finite vertices with k >= 3, got shape "
                                 f"{vertices.shape}")
            vertices.setflags(write=False)
            racks.append(vertices)
        if racks and not np.isfinite(np.concatenate(racks)).all():  # (one test of all the racks' vertices)
            i = next(i for i, vertices in enumerate(racks) if not np.isfinite(vertices).all())
            raise ValueError(f"racks[{i}] must be a (k, 2) array of finite vertices with k >= 3, got a non-finite "
                             f"vertex")
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
    def rack_vertices(self) -> list[np.ndarray]:
        """The racks as (k, 2) vertex arrays, counter-clockwise (a clockwise one reversed as shapely's ``orient``
        does: the first vertex kept, the others backwards); :attr:`polygons` without the walls."""
        out = []
        for v in self.racks:
            v = v[:-1] if len(v) > 3 and (v[0] == v[-1]).all() else v  # a closed ring: shapely drops the repeat
            p = v.tolist()
            clockwise = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(p, p[1:] + p[:1], strict=True)) < 0
            out.append(np.concatenate([v[:1], v[:0:-1]]) if clockwise else np.array(v))
        return out

    @functools.cached_property
    def polygons(self) -> list[np.ndarray]:
        """Every static obstacle (the racks, then the four walls) as a (k, 2) vertex array, counter-clockwise
        (:attr:`rack_vertices`, then :attr:`wall_polygons`)."""
        return [*self.rack_vertices, *self.wall_polygons]

    @functools.cached_property
    def segments(self) -> np.ndarray:
        """Every obstacle edge as (S, 4) segments ``[x0, y0, x1, y1]`` (read-only): the racks' (as given), then the
        hall's four (its inner faces, from :attr:`hall_vertices`); ``polygon_segments`` of them."""
        segments = polygon_segments([*self.racks, self.hall_vertices])
        segments.setflags(write=False)
        return segments

    @functools.cached_property
    def rack_segments(self) -> np.ndarray:
        """The edges of :attr:`rack_vertices` (the racks counter-clockwise) as (R, 4) segments (read-only)."""
        segments = polygon_segments(self.rack_vertices)
        segments.setflags(write=False)
        return segments

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
    length, depth, aisle, cross = uniform(rng, *r._size_bounds).tolist()
    return layout_from_sizes(rows, segments, length, depth, aisle, cross)


def layout_from_sizes(rows: int, segments: int, rack_length: float, rack_depth: float, aisle_width: float,
                      cross_aisle_width: float) -> WarehouseLayout:
    """The regular layout of ``rows`` x ``segments`` racks with these sizes [m] (the hall fits around them)."""
    width = 2 * cross_aisle_width + segments * rack_length + (segments - 1) * cross_aisle_width
    height = (rows + 1) * aisle_width + rows * rack_depth
    flat, boxes = [], []  # the four vertices of every rack (_box_vertices' order), then the hall's; the racks' bounds
    for row in range(rows):
        y0 = -height / 2 + aisle_width + row * (rack_depth + aisle_width)
        for seg in range(segments):
            x0 = -width / 2 + cross_aisle_width + seg * (rack_length + cross_aisle_width)
            x1, y1 = x0 + rack_length, y0 + rack_depth
            flat += (x1, y0, x1, y1, x0, y1, x0, y0)
            boxes += (x0, y0, x1, y1)
    w, h = width / 2, height / 2
    flat += (w, -h, w, h, -w, h, -w, -h)  # hall_vertices'
    rings = np.array(flat, dtype=np.float64).reshape(-1, 4, 2)
    vertices = rings[:-1]
    layout = WarehouseLayout(width=width, height=height, racks=vertices)
    # the cached properties, known without the checks: [xmin, ymin, xmax, ymax] (what rack_boxes finds), and the
    # racks, counter-clockwise already
    layout.__dict__["boxes"] = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    layout.__dict__["rack_vertices"] = list(layout.racks)
    segments = np.concatenate([rings, rings[:, [1, 2, 3, 0]]], axis=2).reshape(-1, 4)  # each vertex and the next
    segments.setflags(write=False)
    layout.__dict__["segments"], layout.__dict__["rack_segments"] = segments, segments[: 4 * len(vertices)]
    return layout


__all__ = ["LayoutRanges", "Roadmap", "WarehouseLayout", "generate_layout", "layout_from_sizes"]
