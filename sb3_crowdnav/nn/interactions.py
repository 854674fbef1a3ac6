"""Pairwise pedestrian-interaction encodings, batched and loop-free.

All functions take positions already in the robot-centric frame (see
:mod:`sb3_crowdnav.nn.transforms`) and a boolean ``present`` mask of the same leading shape;
a pedestrian that is not present never contributes to anyone's encoding, and a pedestrian
never contributes to its own. The encodings depend on the observation only (no parameters).
"""

from __future__ import annotations

import math

import torch as th

from sb3_crowdnav.nn.layers import exporting


def _check_positions(positions: th.Tensor, present: th.Tensor) -> None:
    if positions.dim() < 2 or positions.shape[-1] != 2 or tuple(present.shape) != tuple(positions.shape[:-1]):
        raise ValueError(
            f"expected positions (..., N, 2) and present (..., N) with the same leading shape; got positions "
            f"{tuple(positions.shape)} and present {tuple(present.shape)}"
        )


def _pair_mask(present: th.Tensor) -> th.Tensor:
    """(..., N, N) True where i and j are present and j != i (row i = the encoded pedestrian)."""
    n = present.shape[-1]
    not_self = ~th.eye(n, dtype=th.bool, device=present.device)
    return present[..., :, None] & present[..., None, :] & not_self


def _pairwise_offsets(positions: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """x and y of the vector from pedestrian i to pedestrian j, each (..., N_i, N_j), contiguous.

    Separate contiguous components keep atan2 / hypot on their vectorised kernels (a strided
    (..., 2) layout makes them several times slower).
    """
    x, y = positions[..., 0].contiguous(), positions[..., 1].contiguous()  # (..., N)
    return x[..., None, :] - x[..., :, None], y[..., None, :] - y[..., :, None]


def _edge_tables(num_sectors: int) -> tuple[list[float], list[float], list[int]]:
    """For the edges j * 2π/K, j = -m … m (m = ceil(K / 2)), at index j + m: their cos and sin, with exact 0 and ±1
    on the axes (the edge at 0 rad tests y alone, whatever x is); and at index i + 1, i = -1 … 2m: the sector
    before or at edge i - m, ``(i - m) mod K``."""
    m = -(-num_sectors // 2)
    angles = [2 * math.pi * j / num_sectors for j in range(-m, m + 1)]
    cos = [0.0 if abs(math.cos(a)) < 1e-12 else math.cos(a) for a in angles]
    sin = [0.0 if abs(math.sin(a)) < 1e-12 else math.sin(a) for a in angles]
    return cos, sin, [(i - m) % num_sectors for i in range(-1, 2 * m + 1)]


def sector_of(x: th.Tensor, y: th.Tensor, num_sectors: int) -> th.Tensor:
    """Sector index k of the directions (x, y) (any shape, one float dtype): the angle phi in [0, 2π)
    counter-clockwise from the x-axis lies in ``[k * 2π/K, (k + 1) * 2π/K)``; 0 for (0, 0). Long tensor of the same
    shape.

    Decided by the sign of a cross product with the nearest sector edge's vector (a constant table, exact 0 and ±1
    on the axes), not by the value of an ``atan2``: a product and a difference are rounded alike by every IEEE
    runtime, so PyTorch and an exported graph in ONNX Runtime put a direction on the same side of an edge even
    1e-12 rad from it (their float32 ``atan2`` kernels differ in the last bit there). A float32 ``atan2`` only picks
    the nearest edge; where two runtimes could pick different ones (half-way between edges), either edge's test
    gives the same sector. Index arithmetic by table look-ups (``take``): integer ``where`` and ``remainder`` cost
    more than the rest together.
    """
    if num_sectors <= 2:  # no sector narrower than a half-turn: the half-planes decide alone
        lower = (y < 0) | ((y == 0) & (x < 0))
        return lower.long() if num_sectors == 2 else th.zeros_like(x, dtype=th.long)
    cos, sin, sectors = (th.tensor(table, dtype=dtype, device=x.device)
                         for table, dtype in zip(_edge_tables(num_sectors), (x.dtype, x.dtype, th.long), strict=True))
    m = -(-num_sectors // 2)
    nearest = th.round(th.atan2(y.float(), x.float()) * (num_sectors / (2 * math.pi))) + m  # edge index, [0, 2m]
    # (±0, ±0), where atan2 may give ±π: edge 0, whose cross product 0 keeps it in sector 0
    nearest = th.where((x == 0) & (y == 0), float(m), nearest).long()
    behind = th.take(cos, nearest) * y - th.take(sin, nearest) * x < 0  # clockwise of the edge: the sector before
    return th.take(sectors, nearest + 1 - behind.long())


def angular_pedestrian_grid(
    positions: th.Tensor, present: th.Tensor, num_sectors: int = 12, r_max: float = 3.0, axis: th.Tensor | None = None
) -> th.Tensor:
    """Angular pedestrian grid of every pedestrian (paper Eq. 3).

    ``grid[..., i, k] = min(r_max, min{ rho_ij : j present, j != i, phi_ij in sector k })`` and
    ``r_max`` for an empty sector, where (rho_ij, phi_ij) are the polar coordinates of
    pedestrian j around pedestrian i (centre distance [m]). Sector k covers
    ``phi in [k * 2π/K, (k + 1) * 2π/K)``, with phi measured **counter-clockwise from** ``axis``
    (default: the x-axis of the frame of ``positions``; the extractor gives world positions and the
    robot-to-goal vector), k = 0 … K-1. A coincident pedestrian (rho = 0) falls in sector 0, as does
    everyone for a zero ``axis``'s default (the x-axis). Rows of pedestrians that are not present are all
    ``r_max``. The sectors are decided by the signs of products and sums (:func:`sector_of`), which every IEEE
    runtime rounds alike: an exported graph puts every pedestrian in PyTorch's sector.

    :param positions: (..., N, 2) pedestrian centres [m]
    :param present: (..., N) bool
    :param num_sectors: K
    :param r_max: grid radius [m]
    :param axis: (..., 2) the direction of sector 0's first edge in the frame of ``positions`` (any length, same
        dtype; a zero vector means the x-axis), or None for the x-axis
    :return: (..., N, K)
    """
    _check_positions(positions, present)
    if axis is not None and tuple(axis.shape) != (*positions.shape[:-2], 2):
        raise ValueError(f"expected axis {(*positions.shape[:-2], 2)} for positions {tuple(positions.shape)}, got "
                         f"{tuple(axis.shape)}")
    dx, dy = _pairwise_offsets(positions)  # (..., N_i, N_j) from i to j
    rho = th.hypot(dx, dy)
    x, y = dx, dy
    if axis is not None:  # the offsets in the axis's frame, scaled by its length (products and sums: exact rounding)
        ax, ay = (axis[..., c][..., None, None] for c in (0, 1))
        ax = th.where((ax == 0) & (ay == 0), th.ones((), dtype=ax.dtype), ax)
        x, y = ax * dx + ay * dy, ax * dy - ay * dx
    sector = sector_of(x, y, num_sectors)  # (..., N, N) in [0, K)
    dist = th.where(_pair_mask(present), th.clamp(rho, max=r_max), th.full((), r_max, dtype=rho.dtype))
    rows = positions.new_full((*positions.shape[:-1], num_sectors), r_max)  # (..., N, K)
    # scatter each pair's distance into (row i, sector of j) and keep the minimum
    return rows.scatter_reduce_(-1, sector, dist, reduce="amin", include_self=True)


def local_occupancy_map(
    positions: th.Tensor, velocities: th.Tensor, present: th.Tensor, cell_num: int = 4, cell_size: float = 1.0
) -> th.Tensor:
    """Local map around every pedestrian, as the field's OM-SARL (three channels per cell).

    The map of pedestrian i is a ``cell_num x cell_num`` grid of ``cell_size`` cells centred
    on i, its x-axis along i's velocity (the frame's x-axis when i stands still). For every
    cell: the number of other present pedestrians whose centre lies in it, and their mean
    velocity (vx, vy) in the same rotated axes (0 for an empty cell). Cell index
    ``row * cell_num + col`` with ``col = floor(x / cell_size + cell_num / 2)`` (x forward) and
    ``row`` the same for y.

    :param positions: (..., N, 2) [m]
    :param velocities: (..., N, 2) [m/s]
    :param present: (..., N) bool
    :return: (..., N, cell_num * cell_num * 3), per cell [count, mean vx, mean vy]
    """
    _check_positions(positions, present)
    angle = th.atan2(velocities[..., 1], velocities[..., 0])  # (..., N)
    cos, sin = th.cos(angle)[..., :, None], th.sin(angle)[..., :, None]  # (..., N_i, 1)

    def in_frame_of_i(v: th.Tensor) -> th.Tensor:  # (..., N_i, N_j, 2) rotated by i's heading
        return th.stack((cos * v[..., 0] + sin * v[..., 1], cos * v[..., 1] - sin * v[..., 0]), dim=-1)

    rel = in_frame_of_i(positions[..., None, :, :] - positions[..., :, None, :])  # (..., N, N, 2)
    vel = in_frame_of_i(velocities[..., None, :, :].expand_as(rel))  # (..., N, N, 2)
    cell = th.floor(rel / cell_size + cell_num / 2)  # (..., N, N, 2)
    inside = ((cell >= 0) & (cell < cell_num)).all(dim=-1) & _pair_mask(present)  # (..., N, N)
    index = (cell[..., 1] * cell_num + cell[..., 0]).clamp(0, cell_num * cell_num - 1).long()
    one_hot = th.nn.functional.one_hot(index, cell_num * cell_num).to(positions.dtype)
    one_hot = one_hot * inside[..., None]  # (..., N_i, N_j, C)
    ones = th.ones_like(vel[..., :1])
    sums = th.einsum("...jc,...jf->...cf", one_hot, th.cat((ones, vel), dim=-1))  # (..., N, C, 3)
    count = sums[..., :1]
    mean_vel = sums[..., 1:] / count.clamp(min=1.0)
    return th.cat((count, mean_vel), dim=-1).flatten(-2)


def social_forces(
    positions: th.Tensor,
    radii: th.Tensor,
    present: th.Tensor,
    robot_radius: th.Tensor,
    strength: float = 2.1,
    range_: float = 0.3,
) -> tuple[th.Tensor, th.Tensor]:
    """Helbing-Molnár repulsive social forces (circular form) of the crowd.

    ``f_ij = A * exp((r_i + r_j - d_ij) / B) * n_ij`` with n_ij the unit vector from j to i
    (A = ``strength`` [m/s²], B = ``range_`` [m]). Returns, for every pedestrian i, the sum of
    the forces from the other present pedestrians on i, and the force that i exerts on the
    robot (which sits at the origin of the robot-centric frame). Coincident centres give a
    zero direction, so the result stays finite.

    :param positions: (..., N, 2) robot-centric [m]
    :param radii: (..., N) [m]
    :param present: (..., N) bool
    :param robot_radius: (...) [m]
    :return: force on each pedestrian from the others (..., N, 2) and force of each on the robot (..., N, 2)
    """
    _check_positions(positions, present)
    if exporting():
        return _social_forces_by_component(positions, radii, present, robot_radius, strength, range_)
    diff = positions[..., :, None, :] - positions[..., None, :, :]  # (..., N_i, N_j, 2): from j to i
    dist = th.linalg.vector_norm(diff, dim=-1, keepdim=True)  # (..., N, N, 1)
    unit = diff / dist.clamp(min=1e-6)
    radius_sum = (radii[..., :, None] + radii[..., None, :])[..., None]
    magnitude = th.where(_pair_mask(present)[..., None], strength * th.exp((radius_sum - dist) / range_), 0.0)
    on_human = (magnitude * unit).sum(dim=-2)  # (..., N, 2)
    to_robot = -positions  # from pedestrian i to the robot at the origin
    d_robot = th.linalg.vector_norm(to_robot, dim=-1, keepdim=True)  # (..., N, 1)
    mag_robot = strength * th.exp((radii[..., None] + robot_radius[..., None, None] - d_robot) / range_)
    on_robot = th.where(present[..., None], mag_robot * to_robot / d_robot.clamp(min=1e-6), 0.0)
    return on_human, on_robot


def _social_forces_by_component(positions: th.Tensor, radii: th.Tensor, present: th.Tensor, robot_radius: th.Tensor,
                                strength: float, range_: float) -> tuple[th.Tensor, th.Tensor]:
    """:func:`social_forces` in an exported graph: the same terms on separate x and y tensors (..., N, N), so that no
    operator broadcasts over a last axis of 1 or 2, which ONNX Runtime runs element by element (the pairwise terms
    took a third of ``sf_rl``'s graph); equal to the eager form but for the last bits of the sums."""
    px, py = positions[..., 0], positions[..., 1]  # (..., N)
    dx, dy = px[..., :, None] - px[..., None, :], py[..., :, None] - py[..., None, :]  # (..., N_i, N_j): from j to i
    dist = th.sqrt(dx * dx + dy * dy)
    clamped = dist.clamp(min=1e-6)
    radius_sum = radii[..., :, None] + radii[..., None, :]
    magnitude = th.where(_pair_mask(present), strength * th.exp((radius_sum - dist) / range_), 0.0)
    on_human = th.stack(((magnitude * (dx / clamped)).sum(dim=-1), (magnitude * (dy / clamped)).sum(dim=-1)), dim=-1)
    d_robot = th.sqrt(px * px + py * py)  # (..., N): the robot at the origin
    mag_robot = strength * th.exp((radii + robot_radius[..., None] - d_robot) / range_)
    scale = th.where(present, mag_robot / d_robot.clamp(min=1e-6), 0.0)
    return on_human, th.stack((scale * -px, scale * -py), dim=-1)
