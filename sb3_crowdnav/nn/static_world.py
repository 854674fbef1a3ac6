"""The warehouse's static world for the crowd encoders: nearby rack and wall segments, and the route.

Every extractor of :mod:`sb3_crowdnav.nn.extractors` gets this branch when (and only when) its observation
space has the warehouse keys (``obstacles``, ``obstacles_mask``, ``waypoints``): its output is appended to the
crowd features. An open-floor extractor builds no extra parameter, so models of ``CrowdNav-v0`` are unchanged.

Frame: the same robot-centric frame as the pedestrians (:func:`~sb3_crowdnav.nn.transforms.robot_centric`),
origin at the robot, x-axis from the robot to its **goal**. Each observed segment becomes its two endpoints, its
point closest to the robot and that distance, encoded by an MLP per segment and max-pooled over the present
segments (padding never enters the pool: permutation- and padding-invariant); the waypoints are expressed in the
same frame and appended as they are.
"""

from __future__ import annotations

import torch as th
from torch import nn

from sb3_crowdnav.nn.layers import mlp
from sb3_crowdnav.nn.transforms import goal_frame, rotate
from sb3_crowdnav.sim.observation import SEGMENT_DIM, ObservationSchema, Robot

SEGMENT_FEATURES = 7  # endpoints (4), closest point (2), its distance (1)


class StaticWorldEncoder(nn.Module):
    """Segments (pooled) and waypoints in the robot-to-goal frame: (B, ``features_dim``).

    :param schema: the observation's schema (``max_obstacles`` and ``num_waypoints`` > 0)
    :param arch: hidden sizes of the per-segment MLP; the pooled size is the last one
    """

    def __init__(self, schema: ObservationSchema, arch: tuple[int, ...] = (64, 32)) -> None:
        super().__init__()
        self.max_obstacles, self.num_waypoints = schema.max_obstacles, schema.num_waypoints
        self.segment_mlp = mlp(SEGMENT_FEATURES, list(arch), last_activation=True)
        self.pooled_dim = arch[-1]
        self.features_dim = self.pooled_dim + 2 * self.num_waypoints

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        robot = observations["robot"]
        batch = robot.shape[0]
        segments = observations["obstacles"].reshape(batch, self.max_obstacles, SEGMENT_DIM)  # (B, S, 4)
        present = observations["obstacles_mask"] > 0.5  # (B, S)
        _, cos, sin = goal_frame(robot)
        origin = robot[:, None, Robot.POS]
        a = rotate(segments[..., :2] - origin, cos, sin)  # (B, S, 2)
        b = rotate(segments[..., 2:] - origin, cos, sin)
        ab = b - a
        t = (-(a * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)  # closest point to the robot
        closest = a + t[..., None] * ab
        features = th.cat((a, b, closest, closest.norm(dim=-1, keepdim=True)), dim=-1)  # (B, S, 7)
        features = th.where(present[..., None], features, th.zeros((), dtype=features.dtype))  # padding may hold NaN
        encoded = self.segment_mlp(features)  # (B, S, H), >= 0 after the ReLU
        pooled = th.where(present[..., None], encoded, th.zeros((), dtype=encoded.dtype)).amax(dim=1)  # (B, H)
        waypoints = observations["waypoints"].reshape(batch, self.num_waypoints, 2)
        route = rotate(waypoints - origin, cos, sin).reshape(batch, -1)  # (B, 2K)
        return th.cat((pooled, route), dim=1)
