"""From the world-frame observation (:mod:`sb3_crowdnav.sim.observation`) to robot-centric tensors.

The robot-centric frame has its origin at the robot's **current** position and its x-axis
pointing from the robot to its goal (y-axis counter-clockwise from it), as in the field's
CrowdNav ``rotate()``. Every pedestrian history step is expressed in this same frame (the
observation carries the robot's current pose only), so the frame is invariant to
translations and rotations of the world.

Robot features (``ROBOT_FEATURES``, 7 values):
    dist_goal, v_pref, vx, vy (velocity in the frame), radius,
    cos and sin of the heading relative to the goal axis (continuous, no wrap-around jump).
Per (history step, pedestrian) features (``HUMAN_FEATURES``, 7 values):
    px, py, vx, vy (in the frame), radius, dist (centre distance to the robot), radius_sum.

Columns of the outputs are named by ``RobotFeat`` / ``HumanFeat``; columns of the inputs by
:mod:`sb3_crowdnav.sim.observation`.
"""

from __future__ import annotations

import torch as th
from gymnasium import spaces

from sb3_crowdnav.nn.interactions import angular_pedestrian_grid
from sb3_crowdnav.sim.observation import OBS_KEYS, ROBOT_DIM, Human, ObservationSchema, Robot

ROBOT_FEATURES = ("dist_goal", "v_pref", "vx", "vy", "radius", "cos_heading", "sin_heading")
HUMAN_FEATURES = ("px", "py", "vx", "vy", "radius", "dist", "radius_sum")
ROBOT_FEATURE_DIM = len(ROBOT_FEATURES)
HUMAN_FEATURE_DIM = len(HUMAN_FEATURES)


class RobotFeat:
    """Columns of the robot-centric robot features (batch, 7)."""

    DIST_GOAL = 0
    V_PREF = 1
    VEL = slice(2, 4)
    RADIUS = 4
    HEADING = slice(5, 7)  # cos, sin


class HumanFeat:
    """Columns of the robot-centric pedestrian features (..., 7)."""

    POS = slice(0, 2)
    VEL = slice(2, 4)
    RADIUS = 4
    DIST = 5
    RADIUS_SUM = 6


def parse_observation_space(observation_space: spaces.Space) -> tuple[int, int]:
    """Validate a crowd observation space and return ``(history_length, max_humans)`` (see
    :meth:`~sb3_crowdnav.sim.observation.ObservationSchema.from_space`)."""
    schema = ObservationSchema.from_space(observation_space)
    return schema.history_length, schema.max_humans


def split_observation(
    observations: dict[str, th.Tensor], history_length: int, max_humans: int, zero_padding: bool = True
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Check shapes and return robot (B, 9), humans (B, T, N, 5), present (B, N) bool.

    With ``zero_padding`` the padded slots of ``humans`` are replaced by zeros (they may hold
    anything, even NaN); without, the caller must never let them through.
    """
    schema = ObservationSchema(history_length, max_humans)
    robot, humans, mask = (observations[k] for k in OBS_KEYS)
    batch = robot.shape[0] if robot.dim() == 2 else -1
    expected = {k: (batch, *shape) for k, shape in schema.shapes.items()}
    if robot.dim() != 2 or any(tuple(observations[k].shape) != shape for k, shape in expected.items()):
        raise ValueError(
            f"expected observation tensors robot (B, {ROBOT_DIM}), humans (B, {schema.shapes['humans'][0]}) "
            f"and humans_mask (B, {max_humans}); got robot {tuple(robot.shape)}, humans {tuple(humans.shape)}, "
            f"humans_mask {tuple(mask.shape)}"
        )
    present = mask > 0.5  # never detect padding by value: a present human may sit at (0, 0)
    humans = schema.humans_view(humans)
    if zero_padding:  # replace, do not multiply: NaN * 0 is NaN
        humans = th.where(present[:, None, :, None], humans, th.zeros((), dtype=humans.dtype))
    return robot, humans, present


def goal_frame(robot: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Distance to goal, cos and sin of the goal-axis angle, each (B,), from robot (B, 9)."""
    to_goal = robot[:, Robot.GOAL] - robot[:, Robot.POS]  # (B, 2)
    angle = th.atan2(to_goal[:, 1], to_goal[:, 0])  # atan2(0, 0) = 0: a robot on its goal keeps the world x-axis
    return th.linalg.vector_norm(to_goal, dim=1), th.cos(angle), th.sin(angle)


def rotate(xy: th.Tensor, cos: th.Tensor, sin: th.Tensor) -> th.Tensor:
    """Express world vectors xy (B, ..., 2) in the frame rotated by the angle with cos, sin (B,)."""
    shape = (-1,) + (1,) * (xy.dim() - 2)
    c, s = cos.view(shape), sin.view(shape)
    x, y = xy[..., 0], xy[..., 1]
    return th.stack((c * x + s * y, c * y - s * x), dim=-1)


def robot_centric(robot: th.Tensor, humans: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """Robot features (B, 7) and per (step, pedestrian) features (B, T, N, 7) in the robot-to-goal frame."""
    dist_goal, cos, sin = goal_frame(robot)  # (B,) each
    heading = robot[:, Robot.HEADING]
    robot_feats = th.cat(
        (
            dist_goal[:, None],
            robot[:, Robot.V_PREF : Robot.V_PREF + 1],
            rotate(robot[:, Robot.VEL], cos, sin),
            robot[:, Robot.RADIUS : Robot.RADIUS + 1],
            # cos/sin of (heading - goal angle) by the angle-difference identities
            (th.cos(heading) * cos + th.sin(heading) * sin)[:, None],
            (th.sin(heading) * cos - th.cos(heading) * sin)[:, None],
        ),
        dim=1,
    )
    batch, steps, n, _ = humans.shape
    rel = humans[..., Human.POS] - robot[:, None, None, Robot.POS]  # (B, T, N, 2)
    # positions and velocities rotated together by one batched matmul with the rows of R(-angle)
    rotation = th.stack((cos, sin, -sin, cos), dim=1).view(batch, 2, 2)  # (B, 2, 2)
    vectors = th.cat((rel, humans[..., Human.VEL]), dim=-1).view(batch, steps * n * 2, 2)
    rotated = th.bmm(vectors, rotation.transpose(1, 2)).view(batch, steps, n, 4)  # px, py, vx, vy
    radius = humans[..., Human.RADIUS : Human.RADIUS + 1]  # (B, T, N, 1)
    human_feats = th.cat(
        (
            rotated,
            radius,
            th.hypot(rel[..., :1], rel[..., 1:]),
            radius + robot[:, None, None, Robot.RADIUS : Robot.RADIUS + 1],
        ),
        dim=-1,
    )
    return robot_feats, human_feats



def nearest_pedestrian(robot: th.Tensor, humans: th.Tensor, present: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """CADRL's pair in an exported graph: the robot features (B, 7), the latest features (B, 7) of the present
    pedestrian with the smallest surface distance (zeros without anyone) and whether anyone is present (B,), from the
    world-frame robot (B, 9), pedestrians (B, T, M, 5) and ``present`` (B, M).

    The eager extractor sorts the pedestrians and zeroes the padding first, which picks the same pedestrian (but for
    exact ties of the surface distance) with the same features: ONNX Runtime ran the sort, the gather and the
    masking of every slot in 20 % of ``cadrl``'s graph.
    """
    robot_feats, human_feats = robot_centric(robot, humans[:, -1:])
    latest = human_feats[:, -1]  # (B, M, 7)
    surface = latest[..., HumanFeat.DIST] - latest[..., HumanFeat.RADIUS_SUM]
    nearest = th.where(present, surface, th.full((), th.inf, dtype=surface.dtype)).argmin(dim=1)  # (B,)
    human = th.gather(latest, 1, nearest[:, None, None].expand(-1, 1, latest.shape[-1]))[:, 0]
    anyone = present.any(dim=1)
    return robot_feats, th.where(anyone[:, None], human, th.zeros((), dtype=human.dtype)), anyone

def goal_frame_grid(robot: th.Tensor, humans: th.Tensor, valid: th.Tensor, num_sectors: int, r_max: float) -> th.Tensor:
    """The APG (Eq. 3) of every pedestrian and step, (B, T, L, K), sector 0 at the robot-to-goal axis, from the
    world-frame robot (B, 9), pedestrians (B, T, L, 5) and ``valid`` (B, L) (padding ignored, whatever it holds).

    The sectors are those of the world offsets around that axis, decided by exact sign tests
    (:func:`~sb3_crowdnav.nn.interactions.sector_of`): an exported graph puts every pedestrian in PyTorch's sector,
    which it did not from the robot-centric positions (their rotation's cos and sin differ in the last bit).
    """
    batch, steps, width = humans.shape[:3]
    present = valid[:, None, :].expand(batch, steps, width)
    positions = th.where(present[..., None], humans[..., Human.POS], th.zeros((), dtype=humans.dtype))
    axis = (robot[:, Robot.GOAL] - robot[:, Robot.POS])[:, None, :].expand(batch, steps, 2)
    return angular_pedestrian_grid(positions, present, num_sectors, r_max, axis)
