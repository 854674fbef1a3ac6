"""The adapter over ``pyrvo`` (bindings of the reference RVO2 library) and the ORCA robot policy."""

from __future__ import annotations

import numpy as np
import pyrvo

from sb3_crowdnav.sim.actions import action_table, nearest_action
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.layout import HUMAN_DIM, Human, Robot


def preferred_velocity(position: np.ndarray, goal: np.ndarray, v_pref: float) -> np.ndarray:
    """goal - position, normalised to ``v_pref`` only when longer (so agents slow down at the goal)."""
    delta = goal - position
    norm = np.linalg.norm(delta, axis=-1, keepdims=True)
    return np.where(norm > v_pref, delta / np.maximum(norm, 1e-12) * v_pref, delta)


def make_simulator(cfg: SceneConfig, max_speed: float) -> pyrvo.RVOSimulator:
    """An empty RVO2 simulator with SPEC §2's agent defaults."""
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
    """Pedestrians driven by ORCA; optionally the robot as an agent they avoid."""

    def __init__(self, cfg: SceneConfig, positions: np.ndarray, radii: np.ndarray, v_prefs: np.ndarray,
                 robot: tuple[np.ndarray, np.ndarray, float] | None) -> None:
        self.sim = make_simulator(cfg, float(np.max(v_prefs, initial=cfg.human_v_pref)))
        self.n = len(positions)
        for p, r, v in zip(positions, radii, v_prefs):
            self.sim.add_agent(
                (float(p[0]), float(p[1])), cfg.orca_neighbor_dist, cfg.orca_max_neighbors,
                cfg.orca_time_horizon, cfg.orca_time_horizon_obst, float(r), float(v), (0.0, 0.0),
            )
        self.robot_id = None
        if robot is not None:
            pos, vel, radius = robot
            self.robot_id = self.sim.add_agent(
                (float(pos[0]), float(pos[1])), cfg.orca_neighbor_dist, cfg.orca_max_neighbors,
                cfg.orca_time_horizon, cfg.orca_time_horizon_obst, float(radius), cfg.robot_v_pref,
                (float(vel[0]), float(vel[1])),
            )

    def step(self, pref_velocities: np.ndarray, robot_state: tuple[np.ndarray, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Advance one step; return the pedestrians' new positions and velocities, each (N, 2).

        ``robot_state`` = (position, velocity) of the robot at the start of the step, when visible.
        """
        sim = self.sim
        for i in range(self.n):
            sim.set_agent_pref_velocity(i, (float(pref_velocities[i, 0]), float(pref_velocities[i, 1])))
        if self.robot_id is not None and robot_state is not None:
            pos, vel = robot_state
            sim.set_agent_position(self.robot_id, (float(pos[0]), float(pos[1])))
            sim.set_agent_velocity(self.robot_id, (float(vel[0]), float(vel[1])))
            sim.set_agent_pref_velocity(self.robot_id, (float(vel[0]), float(vel[1])))
        sim.do_step()
        pos = np.empty((self.n, 2))
        vel = np.empty((self.n, 2))
        for i in range(self.n):
            p = sim.get_agent_position(i)
            v = sim.get_agent_velocity(i)
            pos[i] = p.x, p.y
            vel[i] = v.x, v.y
        return pos, vel


class OrcaPolicy:
    """ORCA for the robot, behind SB3's ``predict(observation, deterministic)`` call.

    Each decision builds an RVO2 simulator with the robot (preferred velocity towards its goal)
    and the present pedestrians of the observation's latest step (preferred velocity = their
    observed velocity, as a constant-velocity guess), runs one ORCA step and maps the robot's
    new velocity to the **nearest of the 80 actions** in velocity space (Euclidean distance
    between the ORCA velocity and the action's velocity under the env's kinematics). Because
    the action table has no zero speed, a wish to stop becomes the slowest action closest in
    direction.

    :param scene: the env's :class:`SceneConfig` (kinematics, action table, ORCA parameters)
    :param safety_space: extra radius [m] the robot keeps from pedestrians
    """

    def __init__(self, scene: SceneConfig | None = None, safety_space: float = 0.0) -> None:
        self.scene = scene if scene is not None else SceneConfig()
        if not safety_space >= 0:
            raise ValueError(f"safety_space must be >= 0, got {safety_space!r}")
        self.safety_space = float(safety_space)
        self.speeds, self.directions = action_table(self.scene.robot_v_pref, self.scene.rotation_range)

    @classmethod
    def from_env(cls, env, safety_space: float = 0.0) -> OrcaPolicy:
        """Build from a CrowdNav env, a wrapped one, or a VecEnv of them."""
        if hasattr(env, "get_attr"):
            scene = env.get_attr("scene")[0]
        else:
            scene = env.unwrapped.scene
        return cls(scene, safety_space)

    def _act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> int:
        cfg = self.scene
        t_len = cfg.history_length
        latest = humans.reshape(t_len, -1, HUMAN_DIM)[-1]
        present = latest[mask.astype(bool)]
        pos, goal = robot[Robot.POS], robot[Robot.GOAL]
        heading, v_pref, vel = float(robot[Robot.HEADING]), float(robot[Robot.V_PREF]), robot[Robot.VEL]
        sim = make_simulator(cfg, v_pref)
        for h in present:
            hp, hv = h[Human.POS], h[Human.VEL]
            sim.add_agent(
                (float(hp[0]), float(hp[1])), cfg.orca_neighbor_dist, cfg.orca_max_neighbors, cfg.orca_time_horizon,
                cfg.orca_time_horizon_obst, float(h[Human.RADIUS]) + 0.01, float(np.hypot(hv[0], hv[1])) + 1e-3,
                (float(hv[0]), float(hv[1])),
            )
            sim.set_agent_pref_velocity(sim.get_num_agents() - 1, (float(hv[0]), float(hv[1])))
        rid = sim.add_agent(
            (float(pos[0]), float(pos[1])), cfg.orca_neighbor_dist, cfg.orca_max_neighbors, cfg.orca_time_horizon,
            cfg.orca_time_horizon_obst, float(robot[Robot.RADIUS]) + 0.01 + self.safety_space, v_pref,
            (float(vel[0]), float(vel[1])),
        )
        pv = preferred_velocity(pos, goal, v_pref)
        sim.set_agent_pref_velocity(rid, (float(pv[0]), float(pv[1])))
        sim.do_step()
        v = sim.get_agent_velocity(rid)
        to_goal = goal - pos
        return nearest_action(np.array([v.x, v.y]), heading, float(np.arctan2(to_goal[1], to_goal[0])),
                              self.speeds, self.directions, cfg.kinematics)

    def predict(self, observation: dict[str, np.ndarray], state=None, episode_start=None, deterministic: bool = True):
        """Actions for one observation or a batch (VecEnv); returns ``(actions, None)`` like SB3."""
        robot = np.asarray(observation["robot"], dtype=np.float64)
        humans = np.asarray(observation["humans"], dtype=np.float64)
        mask = np.asarray(observation["humans_mask"])
        if robot.ndim == 1:
            return np.array(self._act(robot, humans, mask)), None
        return np.array([self._act(robot[i], humans[i], mask[i]) for i in range(robot.shape[0])]), None
