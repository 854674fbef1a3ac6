"""The adapter over ``pyrvo`` (bindings of the reference RVO2 library) and the ORCA robot policy."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pyrvo

from sb3_crowdnav.sim.actions import action_table, check_kinematics, nearest_velocity, reachable_velocities, step_limits
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import Human, ObservationSchema, Robot
from sb3_crowdnav.sim.validation import check_choice, check_number

BLIND_HORIZON = 1e-3  # [s] the obstacle horizon of the pedestrians in a decision's simulator (see OrcaPolicy._act)
# RVO2 builds its agent tree of this many agents or fewer as one leaf, in the order they were added (pyrvo's
# src/KdTree.cc, RVO_MAX_LEAF_SIZE): a reused simulator of so few agents visits them in the order a new one does
AGENT_LEAF_SIZE = 10


def preferred_velocity(position: np.ndarray, goal: np.ndarray, v_pref: float) -> np.ndarray:
    """goal - position, normalised to ``v_pref`` only when longer (so agents slow down at the goal)."""
    delta = goal - position
    norm = np.linalg.norm(delta, axis=-1, keepdims=True)
    return np.where(norm > v_pref, delta / np.maximum(norm, 1e-12) * v_pref, delta)


def make_simulator(cfg: SceneConfig, max_speed: float) -> pyrvo.RVOSimulator:
    """An empty RVO2 simulator with the scene's ORCA defaults (neighbour distance 10 m, 10 neighbours, horizons 5 s)."""
    return pyrvo.RVOSimulator(
        cfg.time_step,
        cfg.orca_neighbor_dist,
        cfg.orca_max_neighbors,
        cfg.orca_time_horizon,
        cfg.orca_time_horizon_obst,
        cfg.human_radius,
        max_speed,
    )


class OrcaCrowd:
    """Pedestrians driven by ORCA; optionally the robot as an agent they avoid.

    An agent of ``passive`` (and the robot's) is one whose new state this simulator is not asked for: it looks at no
    neighbour and (nearly) no obstacle, so RVO2 spends nothing on its velocity, and the others see it where it is put
    (RVO2 computes an agent's velocity from the others' current position, velocity and radius only). The robot is put
    at its actual state before each step; a passive pedestrian by the caller (:class:`OrcaPair`), from where another
    simulator moved it.
    """

    def __init__(self, cfg: SceneConfig, positions: np.ndarray, radii: np.ndarray, v_prefs: np.ndarray,
                 robot: tuple[np.ndarray, np.ndarray, float] | None,
                 obstacles: list[list[list[float]]] | None = None, passive: Sequence[int] = ()) -> None:
        """:param obstacles: static obstacles, each its counter-clockwise vertices as ``[x, y]`` floats (RVO2's
            boundary clockwise; :attr:`~sb3_crowdnav.sim.crowd.Walls.rvo_vertices`), seen by every agent"""
        # (a simulator is never reused with clear_agents(): RVO2's agent tree keeps pointers to the removed agents)
        self.sim = make_simulator(cfg, max([*np.asarray(v_prefs, dtype=np.float64).tolist(), cfg.human_v_pref]))
        for polygon in obstacles or ():
            self.sim.add_obstacle(polygon)
        if obstacles:
            self.sim.process_obstacles()
        self.n = len(positions)
        args = (cfg.orca_neighbor_dist, cfg.orca_max_neighbors, cfg.orca_time_horizon, cfg.orca_time_horizon_obst)
        blind = (0.0, 0, cfg.orca_time_horizon, BLIND_HORIZON)
        passive = set(passive)
        for i, ((x, y), r, v) in enumerate(zip(
                np.asarray(positions, dtype=np.float64).reshape(-1, 2).tolist(),
                np.asarray(radii, dtype=np.float64).tolist(), np.asarray(v_prefs, dtype=np.float64).tolist(),
                strict=True)):  # (in floats: one conversion per array)
            self.sim.add_agent((x, y), *(blind if i in passive else args), r, v, (0.0, 0.0))
        self.active = [i for i in range(self.n) if i not in passive]
        self.robot_id = None
        if robot is not None:
            pos, vel, radius = robot
            self.robot_id = self.sim.add_agent((float(pos[0]), float(pos[1])), *blind, float(radius), cfg.robot_v_pref,
                                               (float(vel[0]), float(vel[1])))

    def step(self, pref_velocities, robot_state=None) -> tuple[np.ndarray, np.ndarray]:
        """Advance one step; return the pedestrians' new positions and velocities, each (N, 2) (a passive one's as
        RVO2 moved it, looking at no one).

        :param pref_velocities: (N, 2) array or sequence of (vx, vy) pairs
        :param robot_state: ``(position, velocity)`` pairs of the robot at the start of the step, when visible
        """
        if isinstance(pref_velocities, np.ndarray):
            pref_velocities = pref_velocities.tolist()
        self.advance(pref_velocities, robot_state)
        state = np.array(self.rows(range(self.n))).reshape(self.n, 4)
        return state[:, :2], state[:, 2:]

    def advance(self, pref_velocities: list, robot_state=None) -> None:
        """One RVO2 step with the active pedestrians' preferred velocities from ``pref_velocities`` (N pairs) and the
        robot put at ``robot_state`` (see :meth:`step`)."""
        sim = self.sim
        set_pref = sim.set_agent_pref_velocity
        for i in self.active:
            set_pref(i, pref_velocities[i])  # (a pair: pyrvo takes a tuple or a list of two floats)
        if self.robot_id is not None and robot_state is not None:
            (px, py), (vx, vy) = robot_state
            sim.set_agent_position(self.robot_id, (float(px), float(py)))
            sim.set_agent_velocity(self.robot_id, (float(vx), float(vy)))
        sim.do_step()

    def rows(self, indices) -> list[tuple[float, float, float, float]]:
        """The ``(px, py, vx, vy)`` of the pedestrians ``indices``, in floats."""
        get_pos, get_vel = self.sim.get_agent_position, self.sim.get_agent_velocity
        return [get_pos(i).to_tuple() + get_vel(i).to_tuple() for i in indices]

    def move_agent(self, i: int, position: np.ndarray) -> None:
        """Put pedestrian ``i`` at ``position`` (2,) (the warehouse pushes a picker out of a rack it was pressed into)."""
        self.sim.set_agent_position(i, (float(position[0]), float(position[1])))


class OrcaPair:
    """The two simulators of a mixed crowd (:class:`~sb3_crowdnav.sim.crowd.OrcaCrowdModel`): ``blind_crowd`` computes
    the ``blind`` people, ``seeing_crowd`` the ``seeing`` ones and has the robot, each with the other side passive.

    A step advances each simulator (:meth:`OrcaCrowd.advance`, the blind side's first), then reads each side's new
    states and puts them into the other simulator, in one loop per side through pyrvo methods bound once per episode
    (a mixed crowd, the warehouse's default, makes about 40 such calls a step). Putting a person's state into a
    simulator leaves every other agent's as it was, so reading the seeing side after the blind side was put changes
    nothing.
    """

    def __init__(self, blind_crowd: OrcaCrowd, seeing_crowd: OrcaCrowd, blind: list[int], seeing: list[int]) -> None:
        self.crowds, self.blind, self.seeing = (blind_crowd, seeing_crowd), blind, seeing
        b, s = blind_crowd.sim, seeing_crowd.sim
        self._blind_calls = (b.get_agent_position, b.get_agent_velocity, b.set_agent_position, b.set_agent_velocity)
        self._seeing_calls = (s.get_agent_position, s.get_agent_velocity, s.set_agent_position, s.set_agent_velocity)

    def step(self, pref_velocities: list, robot_state: tuple) -> tuple[np.ndarray, np.ndarray]:
        """Advance both simulators; every person's new positions and velocities, each (N, 2), in the people's order.

        :param pref_velocities: N (vx, vy) pairs
        :param robot_state: ``(position, velocity)`` pairs of the robot at the start of the step
        """
        blind_crowd, seeing_crowd = self.crowds
        blind_crowd.advance(pref_velocities)
        seeing_crowd.advance(pref_velocities, robot_state)
        b_pos, b_vel, b_set_pos, b_set_vel = self._blind_calls
        s_pos, s_vel, s_set_pos, s_set_vel = self._seeing_calls
        rows: list = [None] * (len(self.blind) + len(self.seeing))  # each person's (px, py, vx, vy)
        for i in self.blind:
            position, velocity = b_pos(i).to_tuple(), b_vel(i).to_tuple()
            s_set_pos(i, position)
            s_set_vel(i, velocity)
            rows[i] = position + velocity
        for i in self.seeing:
            position, velocity = s_pos(i).to_tuple(), s_vel(i).to_tuple()
            b_set_pos(i, position)
            b_set_vel(i, velocity)
            rows[i] = position + velocity
        state = np.array(rows)
        return state[:, :2], state[:, 2:]


def _set_agent(sim: pyrvo.RVOSimulator, i: int, position: tuple[float, float], radius: float, max_speed: float,
               velocity: tuple[float, float]) -> int:
    """Put agent ``i`` of a reused simulator in the state ``add_agent`` with these values (and the neighbour distance,
    max neighbours and time horizons it was added with) would give it; returns ``i``."""
    sim.set_agent_position(i, position)
    sim.set_agent_velocity(i, velocity)
    sim.set_agent_radius(i, radius)
    sim.set_agent_max_speed(i, max_speed)
    return i


class OrcaPolicy:
    """ORCA for the robot, behind SB3's ``predict(observation, deterministic)`` call.

    Each decision builds an RVO2 simulator with the robot (preferred velocity towards its goal)
    and the present pedestrians of the observation's latest step (preferred velocity = their
    observed velocity, as a constant-velocity guess), runs one ORCA step and maps the robot's
    new velocity to one of the env's actions (80, or 81 with ``actions="with_stop"``):

    * ``mapping="nearest"`` (default, the paper's ORCA row): the action nearest in velocity space
      (Euclidean distance between the ORCA velocity and the action's velocity under the env's
      kinematics). ORCA's small steering corrections (often ~10°) are below half the 22.5°
      spacing of the directions, so they are often rounded away; with an invisible robot this
      gives the paper's low ORCA success (0.33).
    * ``mapping="constrained"``: the nearest action among those that satisfy every ORCA
      half-plane of the robot (the velocities ORCA itself considers collision-free for the time
      horizon); when no action satisfies them all, the nearest action overall. A far better
      driver (and the imitation demonstrator of :class:`~sb3_crowdnav.apg_value.APGValue`).

    With the paper's actions, which have no zero speed, a wish to stop becomes the slowest action closest in
    direction; with ``actions="with_stop"`` it is the stop.

    With the scene's ``max_acceleration`` or ``max_turn_rate``, an action's velocity in both mappings is the one its
    step reaches from the robot's current velocity (:func:`~sb3_crowdnav.sim.actions.apply_action`, the env's and the
    lookahead's rule): ORCA's velocity becomes the action whose reachable velocity is nearest, and the robot
    respects the same limits as any policy in the env.

    In ``CrowdNavWarehouse-v0`` the robot also sees the observed rack and wall segments as RVO2 obstacles and
    heads for its current route waypoint instead of the goal: obstacle-aware, route-following, from the
    observation alone.

    :param scene: the env's :class:`SceneConfig` (kinematics, action table, ORCA parameters)
    :param safety_space: extra radius [m] the robot keeps from pedestrians
    :param mapping: ``"nearest"`` or ``"constrained"`` (see above)
    """

    MAPPINGS = ("nearest", "constrained")

    def __init__(self, scene: SceneConfig | None = None, safety_space: float = 0.0, mapping: str = "nearest") -> None:
        self.scene = scene if scene is not None else SceneConfig()
        check_number("safety_space", safety_space, allow_zero=True)
        check_choice("mapping", mapping, self.MAPPINGS)
        self.mapping = mapping
        self.safety_space = float(safety_space)
        self.speeds, self.directions = action_table(self.scene.robot_v_pref, self.scene.rotation_range,
                                                    self.scene.actions)
        # the last decision's simulator with obstacles: (its segments, its number of pedestrians, the simulator)
        self._obstacle_sim: tuple[bytes, int, pyrvo.RVOSimulator] | None = None

    def __getstate__(self) -> dict:
        """Pickled (and copied) without the reused simulator: a cache, and pyrvo's simulators do not pickle."""
        return {**self.__dict__, "_obstacle_sim": None}

    @classmethod
    def from_env(cls, env, safety_space: float = 0.0, mapping: str = "nearest") -> OrcaPolicy:
        """Build from a CrowdNav env, a wrapped one, or a VecEnv of them."""
        if hasattr(env, "get_attr"):
            scene = env.get_attr("scene")[0]
        else:
            scene = env.unwrapped.scene
        return cls(scene, safety_space, mapping)

    def _velocities(self, robot: np.ndarray, goal_direction: float) -> tuple[np.ndarray, np.ndarray]:
        """The velocity (vx, vy), each (n_actions,) [m/s], each action gives the robot: its command, or with limits the
        velocity its step reaches (the env's rule)."""
        cfg, heading = self.scene, float(robot[Robot.HEADING])
        if cfg.max_acceleration is None and cfg.max_turn_rate is None:
            angles = (heading if cfg.kinematics == "unicycle" else goal_direction) + self.directions
            return self.speeds * np.cos(angles), self.speeds * np.sin(angles)
        (px, py), (vx, vy), (gx, gy) = robot[Robot.POS].tolist(), robot[Robot.VEL].tolist(), robot[Robot.GOAL].tolist()
        # (apply_action's velocities: the same move of every action)
        return reachable_velocities(px, py, heading, vx, vy, gx, gy, self.speeds, self.directions,
                                    check_kinematics(cfg.kinematics), float(cfg.time_step),
                                    *step_limits(cfg.max_acceleration, cfg.max_turn_rate, cfg.time_step))

    @staticmethod
    def _allowed(sim, rid: int, vx: np.ndarray, vy: np.ndarray) -> np.ndarray | None:
        """Boolean mask (n_actions,) of the action velocities (``vx``, ``vy``) inside every ORCA half-plane of agent
        ``rid`` (None: no constraint)."""
        n_lines = sim.get_agent_num_orca_lines(rid)
        if n_lines == 0:
            return None
        get_line = sim.get_agent_orca_line
        lines = np.array([get_line(rid, i) for i in range(n_lines)]).reshape(n_lines, 4, 1)  # (L, [dx dy px py], 1)
        dx, dy, px, py = lines[:, 0], lines[:, 1], lines[:, 2], lines[:, 3]
        # RVO2: velocity v violates line i when det(direction, point - v) > 0 (all lines at once: the same values)
        return (dx * (py - vy) - dy * (px - vx) <= 1e-6).all(axis=0)

    def _act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray, segments: np.ndarray | None = None,
             waypoint: np.ndarray | None = None) -> int:
        """One decision; in the warehouse ``segments`` (S, 4) are RVO2 obstacles and ``waypoint`` (2,) replaces the
        goal as the target of the preferred velocity (the action table stays relative to the goal axis)."""
        cfg = self.scene
        latest = ObservationSchema(cfg.history_length, len(mask)).humans_view(humans)[-1]
        present = latest[mask.astype(bool)]
        r = robot.tolist()
        (px, py), (gx, gy), (vx, vy) = r[Robot.POS], r[Robot.GOAL], r[Robot.VEL]
        v_pref = r[Robot.V_PREF]
        args = (cfg.orca_neighbor_dist, cfg.orca_max_neighbors, cfg.orca_time_horizon, cfg.orca_time_horizon_obst)
        # Only the robot's new velocity is read, and RVO2 computes it from the others' position, velocity and radius
        # alone: the pedestrians look at no neighbour and (nearly) no obstacle, which spares their own ORCA programs.
        blind = (0.0, 0, cfg.orca_time_horizon, BLIND_HORIZON)
        pedestrians = zip(present[:, Human.POS].tolist(), present[:, Human.VEL].tolist(),
                          present[:, Human.RADIUS].tolist(), strict=True)
        robot_radius = r[Robot.RADIUS] + 0.01 + self.safety_space
        sim = self._reusable(segments, len(present)) if segments is not None else None
        if sim is None:
            sim = make_simulator(cfg, v_pref)
            if segments is not None and len(segments):
                for x0, y0, x1, y1 in segments.tolist():
                    sim.add_obstacle([(x0, y0), (x1, y1)])
                sim.process_obstacles()
                self._obstacle_sim = (segments.tobytes(), len(present), sim)
            for (hx, hy), (hvx, hvy), radius in pedestrians:
                i = sim.add_agent((hx, hy), *blind, radius + 0.01, math.hypot(hvx, hvy) + 1e-3, (hvx, hvy))
                sim.set_agent_pref_velocity(i, (hvx, hvy))
            rid = sim.add_agent((px, py), *args, robot_radius, v_pref, (vx, vy))
        else:  # the last decision's simulator: its agents (added with these args) in the state add_agent gives
            for i, ((hx, hy), (hvx, hvy), radius) in enumerate(pedestrians):
                _set_agent(sim, i, (hx, hy), radius + 0.01, math.hypot(hvx, hvy) + 1e-3, (hvx, hvy))
                sim.set_agent_pref_velocity(i, (hvx, hvy))
            rid = _set_agent(sim, len(present), (px, py), robot_radius, v_pref, (vx, vy))
        # preferred_velocity() of one agent, in floats
        tx, ty = (gx, gy) if waypoint is None else waypoint.tolist()
        dx, dy = tx - px, ty - py
        norm = math.sqrt(dx * dx + dy * dy)
        if norm > v_pref:
            dx, dy = dx / max(norm, 1e-12) * v_pref, dy / max(norm, 1e-12) * v_pref
        sim.set_agent_pref_velocity(rid, (dx, dy))
        sim.do_step()
        v = sim.get_agent_velocity(rid)
        goal_direction = math.atan2(gy - py, gx - px)
        vx, vy = self._velocities(robot, goal_direction)
        allowed = self._allowed(sim, rid, vx, vy) if self.mapping == "constrained" else None
        return nearest_velocity(np.array([v.x, v.y]), vx, vy, allowed)

    def _reusable(self, segments: np.ndarray, humans: int) -> pyrvo.RVOSimulator | None:
        """The last decision's simulator with obstacles when it can serve a decision with ``segments`` (S, 4) and
        ``humans`` pedestrians, else None (a new one is built, and kept when it has obstacles).

        Processing the obstacles (RVO2's obstacle tree) costs more than the rest of a decision, and the observed
        segments often stay the same from one step to the next: the simulator is reused when its segments (in the
        same order) and its number of agents are the same and at most :data:`AGENT_LEAF_SIZE`, with every agent put
        in the state ``add_agent`` gives (:func:`_set_agent`): a step computed from the same state, the same decision.
        """
        kept = self._obstacle_sim
        if kept is None or kept[1] != humans or humans >= AGENT_LEAF_SIZE or not len(segments) or \
                kept[0] != segments.tobytes():
            return None
        return kept[2]

    def predict(self, observation: dict[str, np.ndarray], state=None, episode_start=None, deterministic: bool = True):
        """Actions for one observation or a batch (VecEnv); returns ``(actions, None)`` like SB3."""
        robot = np.asarray(observation["robot"], dtype=np.float64)
        humans = np.asarray(observation["humans"], dtype=np.float64)
        mask = np.asarray(observation["humans_mask"])  # keys: sb3_crowdnav.sim.observation.OBS_KEYS
        if robot.ndim == 1:
            return np.array(self._act(robot, humans, mask, *self._static(observation, None))), None
        return np.array([self._act(robot[i], humans[i], mask[i], *self._static(observation, i))
                         for i in range(robot.shape[0])]), None

    @staticmethod
    def _static(observation: dict[str, np.ndarray], i: int | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The observed obstacle segments (S, 4) and the current waypoint (2,) of a warehouse observation."""
        if "obstacles_mask" not in observation:
            return None, None
        pick = (lambda key: np.asarray(observation[key], dtype=np.float64)) if i is None else \
            (lambda key: np.asarray(observation[key][i], dtype=np.float64))
        segments = pick("obstacles").reshape(-1, 4)[pick("obstacles_mask") > 0.5]
        return segments, pick("waypoints")[:2]
