"""The crowd-model seam: one small protocol that moves the people of the open floor, and its models by name.

A crowd model receives the episode's :class:`~sb3_crowdnav.sim.population.People` at reset and, each step, their
preferred velocities (the population's: towards the goal at each person's speed, zero while standing) and the
robot's state; it returns the people's new positions and velocities. Who sees the robot is the population's
(``People.sees_robot``); how a person avoids it is the model's. The simulator never asks which model it has, and
nothing above the simulator sees it: the observation is the same whatever moves the people.

A new model is a class with this constructor and these two methods, its settings (``crowd_kwargs``) a frozen
dataclass in :mod:`sb3_crowdnav.sim.crowd_settings`, and a line in :data:`CROWD_MODELS`. A model that brings its own
episodes, whose people come and go (``"replay"``, :mod:`sb3_crowdnav.sim.replay`), is a :class:`RecordedCrowd`.

The open floor has no walls; the warehouse passes its racks and hall as :class:`Walls` at reset, and a model that can
put a person at a position (ORCA: ``move_person``) lets the warehouse push one pressed into a rack back out."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd_settings import LinearCrowdSettings, OrcaCrowdSettings, SocialForceCrowdSettings
from sb3_crowdnav.sim.orca import OrcaCrowd, OrcaPair
from sb3_crowdnav.sim.population import People
from sb3_crowdnav.sim.replay import ReplayCrowdModel
from sb3_crowdnav.sim.scenarios import Scenario
from sb3_crowdnav.sim.social_force_kernels import first_inside, heading_points, in_square, native_simulation, wall_standoff


class RobotAgent(NamedTuple):
    """The robot as the people see it [m, m/s]: its state at the start of the step and, during a step, where its move
    (computed before the people's) ends, for a model that integrates the robot's path through the step."""

    position: tuple[float, float]
    velocity: tuple[float, float]
    radius: float
    end_position: tuple[float, float] | None = None


@dataclass(frozen=True, eq=False)
class Walls:
    """The static world the people walk in (world frame, [m]): ``hall`` (k, 2), its boundary, counter-clockwise, and the
    ``obstacles`` (racks) inside it, each a (k, 2) counter-clockwise vertex array."""

    hall: np.ndarray
    obstacles: tuple[np.ndarray, ...]

    @functools.cached_property
    def rvo_vertices(self) -> list[list[list[float]]]:
        """For ``pyrvo``'s ``add_obstacle`` in ``[x, y]`` floats, once per episode: the obstacles, then the hall as one
        clockwise boundary (RVO2's way of keeping agents inside)."""
        return [polygon.tolist() for polygon in (*self.obstacles, self.hall[::-1])]

    @functools.cached_property
    def area(self) -> Any:
        """The walkable area, the hall minus the obstacles (a shapely polygon, prepared)."""
        import shapely

        area = shapely.Polygon(self.hall)
        if self.obstacles:
            area = area.difference(shapely.union_all([shapely.Polygon(o) for o in self.obstacles]))
        shapely.prepare(area)
        return area


class CrowdModel(Protocol):
    """What moves the people: built once per env from the scene (its ``crowd_kwargs``), reset per episode."""

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent, walls: Walls | None = None) -> None:
        """Start an episode with ``people`` at their starts, at rest; ``rng`` for a model's own randomness; ``walls``
        the static obstacles (None: the open floor)."""

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        """Advance one time step; the people's new positions and velocities, each (n, 2).

        :param preferred: each person's preferred velocity for this step
        :param robot: the robot's state at the start of the step
        """


@runtime_checkable
class RecordedCrowd(CrowdModel, Protocol):
    """A crowd model that brings its own episodes (a recording): it places the robot and the people at reset, and its
    people come and go. The simulator then takes the scenario from :meth:`draw_scenario` instead of drawing one, and
    after the reset and each step reads who is present; its ``n`` slots are the episode's (at most ``max_humans``),
    an absent person's slot padded (zeros, mask 0) and a slot a person arrives in starting its history anew (its
    first state repeated, as at reset)."""

    present: np.ndarray  # (n,) bool: who is present after the reset or the last step
    arrivals: np.ndarray  # (n,) bool: the slots a person took at the reset or the last step
    velocities: np.ndarray  # (n, 2) [m/s] the people's velocities at the episode's first step

    def draw_scenario(self, rng: np.random.Generator) -> Scenario:
        """The episode's places (``human_starts`` (n, 2), zeros in an empty slot); ``rng`` for its draws."""


class OrcaCrowdModel:
    """People driven by ORCA (RVO2 through pyrvo), the paper's crowd.

    Those who see the robot have it as one more ORCA agent at its actual position and velocity; the others ignore it.
    With everyone on one side, one RVO2 simulator runs (with or without the robot); with a mixed crowd, two, each
    computing its side's people (the others passive in it, :class:`~sb3_crowdnav.sim.orca.OrcaCrowd`) and given the
    other side's new states after each step: ORCA computes a person's velocity from its neighbours' current states
    only, so this is each person avoiding exactly the agents it sees.
    """

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.settings: OrcaCrowdSettings = scene.crowd_kwargs
        self.crowds: list[OrcaCrowd] = []
        self.seeing = np.zeros(0, dtype=bool)
        self._pair: OrcaPair | None = None  # a mixed crowd's two simulators

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent, walls: Walls | None = None) -> None:
        radii = people.radii + self.settings.safety_space
        robot_agent = (np.array(robot.position), np.array(robot.velocity), robot.radius)
        self.seeing = people.sees_robot.copy()
        seeing, blind = [[i for i, s in enumerate(self.seeing.tolist()) if s == side] for side in (True, False)]
        self.sides = [side for side in (blind, seeing) if side]  # the people of each simulator, in order
        obstacles = walls.rvo_vertices if walls is not None else None
        # each simulator computes its side's people, the other side's passive in it (OrcaCrowd)
        self.crowds = [OrcaCrowd(self.scene, people.starts, radii, people.v_prefs, robot_agent if side is seeing else None,
                                 obstacles, passive=blind if side is seeing else seeing) for side in self.sides]
        self._pair = OrcaPair(*self.crowds, *self.sides) if len(self.crowds) == 2 else None

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        robot_state = (robot.position, robot.velocity)
        if self._pair is not None:
            return self._pair.step(preferred, robot_state)
        if not self.crowds:  # nobody
            return np.zeros((0, 2)), np.zeros((0, 2))
        return self.crowds[0].step(preferred, robot_state)

    def move_person(self, i: int, position: np.ndarray) -> None:
        """Put person ``i`` at ``position`` (2,) (the warehouse pushes a person pressed into a rack back out)."""
        for crowd in self.crowds:
            crowd.move_agent(i, position)


class LinearCrowdModel:
    """People who walk at their preferred velocity, seeing no one (exact integration; for tests)."""

    def __init__(self, scene: SceneConfig) -> None:
        self.time_step = scene.time_step
        self.settings: LinearCrowdSettings = scene.crowd_kwargs
        self.positions: list[list[float]] = []

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent, walls: Walls | None = None) -> None:
        self.positions = people.starts.tolist()

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        dt = self.time_step
        self.positions = [[x + vx * dt, y + vy * dt] for (x, y), (vx, vy) in zip(self.positions, preferred, strict=True)]
        return np.array(self.positions).reshape(-1, 2), np.array(preferred, dtype=np.float64).reshape(-1, 2)


JUPEDSIM_VERSION = "1.4.2"  # the model calls its compiled layer (social_force_kernels.native_simulation): pinned
JUPEDSIM_INSTALL = f'pip install --no-deps "jupedsim=={JUPEDSIM_VERSION}" deprecated wrapt'
PERSON_MASS = 80.0  # [kg] JuPedSim's default, Helbing et al. (2000)'s
# the robot's agent follows the robot's path (its velocity set each sub-step): so heavy and slow to react that neither
# the people's forces nor a driving force move it off that path ([kg], [s])
ROBOT_MASS, ROBOT_RELAXATION = 1e9, 1e9
TARGET_AHEAD = 1.0  # [m] a person heads for a point this far along its preferred velocity (inside the walkable area)
OPEN_FLOOR_MARGIN = 10.0  # [m] the open floor's walkable area: a square this much beyond the starts and goals
# explicit (symplectic Euler) integration of a force of stiffness k [N/m] on a mass m is stable while h sqrt(k/m) < 2;
# the repulsions' stiffness at contact is A / B, the contact (body) force's JuPedSim's 120000 kg/s², which bodies meet
# when squeezed. Kept below 1.5: at 0.25 s, 5 sub-steps (h sqrt(k/m) = 1.9) still blew a few pickers out of the
# warehouse in 1500 steps, 7 (1.4) none in 3000 (docs/decisions.md)
STABILITY_BOUND = 1.5
BODY_FORCE = 120000.0  # [kg/s²] JuPedSim's SocialForceModel default, Helbing et al. (2000)'s k


def import_jupedsim() -> Any:
    """JuPedSim, or an ``ImportError`` saying how to install it (without the Qt/VTK of its viewer)."""
    try:
        import jupedsim
    except ImportError as error:
        raise ImportError(f"crowd='social_force' needs JuPedSim, installed without the Qt/VTK of its trajectory viewer: "
                          f"{JUPEDSIM_INSTALL} (see docs/installation.md)") from error
    if jupedsim.__version__ != JUPEDSIM_VERSION:
        raise ImportError(f"crowd='social_force' needs JuPedSim {JUPEDSIM_VERSION} (it calls its compiled layer), "
                          f"found {jupedsim.__version__}: {JUPEDSIM_INSTALL}")
    return jupedsim


def min_sub_steps(settings: SocialForceCrowdSettings, time_step: float) -> int:
    """The fewest sub-steps that integrate ``settings``' repulsions and the contact force stably at ``time_step`` [s]."""
    stiffness = max(settings.person_strength / settings.force_range, settings.wall_strength / settings.force_range,
                    BODY_FORCE) / PERSON_MASS  # [1/s²]
    return math.floor(time_step * math.sqrt(stiffness) / STABILITY_BOUND) + 1


class SocialForceCrowdModel:
    """People driven by Helbing's social force model, JuPedSim's ``SocialForceModel`` (C++), with walls.

    Each env step sets every person's target (:data:`TARGET_AHEAD` along its preferred velocity, kept inside the
    walkable area) and desired speed (the preferred velocity's length) and runs ``sub_steps`` JuPedSim iterations.
    The walkable area is the warehouse's hall minus its racks, or on the open floor a square
    :data:`OPEN_FLOOR_MARGIN` beyond the scene; one JuPedSim simulation is built per area and kept, a reset removing
    and adding the agents.

    A robot the people see (``robot_visible=True``) is one more agent, so heavy that nobody moves it, whose velocity is
    set before each sub-step so that it follows the robot's straight path through the step: the people feel it where
    it is at each sub-step. JuPedSim's forces act on every agent in range, so a share of people seeing the robot is
    refused. The robot's agent leaves the model while the robot is outside the walkable area and comes back when it
    is inside again.

    A person pushed out of the walkable area (with ``wall_strength=0``, or squeezed through a wall) leaves the model:
    it stands, at rest, where it was at the start of that step for the rest of the episode, and the others no longer
    feel it.
    """

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.settings: SocialForceCrowdSettings = scene.crowd_kwargs
        if not isinstance(scene.robot_visible, bool):
            raise ValueError(f"robot_visible must be True or False with crowd='social_force', got the share "
                             f"{scene.robot_visible!r}: its forces act on everyone in range, so nobody can ignore the "
                             f"robot while others feel it")
        need = min_sub_steps(self.settings, scene.time_step)
        if self.settings.sub_steps is not None and self.settings.sub_steps < need:
            raise ValueError(f"crowd_kwargs['sub_steps'] must be >= {need} for these strengths and force_range at "
                             f"time_step={scene.time_step} s (the integration would blow up), got "
                             f"{self.settings.sub_steps}")
        self.jps = import_jupedsim()
        self.sub_steps = need if self.settings.sub_steps is None else self.settings.sub_steps
        self.h = scene.time_step / self.sub_steps  # [s]
        self._half: float | None = None  # the open floor's area, the square [-half, half]², tested by its bounds
        self._sim: Any = None
        self._native: Any = None  # the simulation's compiled object (see _fetch)
        self._walls: Walls | None = None
        self._area: Any = None
        self._route = (0, 0)  # the journey and its one direct-steering stage
        self._ids: list[int] = []
        self._agents: list[Any] = []  # their JuPedSim handles, fetched again when the agents change
        self._any_frozen = False  # self.frozen.any()
        self._robot_handle: Any = None
        self._robot: int | None = None  # the robot's agent id while it is in the model
        self._changed = False  # an agent was marked for removal: handles fetched again after the next iteration
        self.positions = np.zeros((0, 2))
        self.frozen = np.zeros(0, dtype=bool)  # people who left the walkable area

    def stops_short(self, clearance: float, speed: float, slowing: bool = True) -> float:
        """How far short [m] of a point ``clearance`` [m] off a wall (between the person's body and the wall) a person
        heading for it comes to rest, facing the wall: where the wall's push, ``wall_strength · exp(-(clearance +
        d) / force_range)``, balances its driving force, ``mass · v / relaxation_time``, its preferred speed v
        ``speed`` [m/s], or with ``slowing`` the distance d left per second, at most ``speed``; 0 without a wall
        force. The warehouse's pickers reach a waypoint or a pick slot within this much more of it
        (:mod:`sb3_crowdnav.sim.warehouse.pickers`)."""
        s = self.settings
        return wall_standoff(s.wall_strength, s.force_range, s.relaxation_time, PERSON_MASS, clearance, speed, slowing)

    def _open_floor(self) -> Any:
        import shapely

        s = self.scene
        half = max(s.circle_radius, s.square_width / 2) + s.start_noise + OPEN_FLOOR_MARGIN
        self._half = half
        return shapely.box(-half, -half, half, half)

    def _inside(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: ``points`` (n, 2) in the walkable area (the open floor's open square by its bounds: cheaper)."""
        if self._half is not None:
            return in_square(points, self._half)
        import shapely

        return shapely.contains_xy(self._area, points[:, 0], points[:, 1])

    def _simulation(self, walls: Walls | None) -> Any:
        """The JuPedSim simulation of ``walls``' area (of the open floor for None), emptied: built once per area."""
        jps = self.jps
        if self._sim is None or walls is not self._walls:
            import shapely

            self._half = None
            self._area = walls.area if walls is not None else self._open_floor()
            shapely.prepare(self._area)
            self._sim = jps.Simulation(model=jps.SocialForceModel(), geometry=self._area, dt=self.h)
            self._native = native_simulation(self._sim)
            stage = self._sim.add_direct_steering_stage()
            self._route = (self._sim.add_journey(jps.JourneyDescription([stage])), stage)
            self._walls = walls
        elif self._native.agent_count():
            for agent in list(self._native.agents()):
                self._native.mark_agent_for_removal(agent.id)
            self._native.iterate()  # removes them (and empties the neighbour grid, which add_agent checks)
        return self._sim

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent, walls: Walls | None = None) -> None:
        self._simulation(walls)
        s, (journey, stage) = self.settings, self._route
        person = functools.partial(
            self.jps.native.SocialForceModelAgentParameters, orientation=(1.0, 0.0), journey_id=journey,
            stage_id=stage, velocity=(0.0, 0.0), mass=PERSON_MASS, reaction_time=s.relaxation_time,
            agent_scale=s.person_strength, obstacle_scale=s.wall_strength, force_distance=s.force_range)
        add = self._native.add_agent
        self._ids = [add(person(position=(x, y), desired_speed=speed, radius=radius))
                     for (x, y), radius, speed in zip(people.starts.tolist(), people.radii.tolist(),
                                                      people.v_prefs.tolist(), strict=True)]
        self._robot = None
        if self.scene.robot_visible:
            self._add_robot(robot.position, robot.radius)
        self.positions = np.array(people.starts, dtype=np.float64).reshape(-1, 2)
        self.frozen = np.zeros(people.n, dtype=bool)
        self._any_frozen = False
        self._fetch()

    def _add_robot(self, position: tuple[float, float], radius: float) -> None:
        """The robot's agent at ``position`` when the robot is inside the walkable area and can be placed there."""
        if not self._inside(np.array([position]))[0]:
            return
        journey, stage = self._route
        try:
            self._robot = self._native.add_agent(self.jps.native.SocialForceModelAgentParameters(
                position=tuple(position), orientation=(1.0, 0.0), journey_id=journey, stage_id=stage,
                velocity=(0.0, 0.0), mass=ROBOT_MASS, desired_speed=0.0, reaction_time=ROBOT_RELAXATION,
                agent_scale=0.0, obstacle_scale=0.0, force_distance=self.settings.force_range, radius=radius))
        except RuntimeError:  # JuPedSim refuses it within half its radius of a wall (the robot collided): next step
            self._robot = None

    def _fetch(self) -> None:
        """The JuPedSim handles (agent, model state) of the people (None for one out of the model) and of the robot's
        agent: pointers into JuPedSim's agents, fetched again whenever an agent is added or removed (kept between:
        finding an agent and its model state costs more than setting them)."""
        agents = [None if frozen else self._native.agent(i) for i, frozen in zip(self._ids, self.frozen.tolist(),
                                                                                strict=True)]
        self._agents = [None if agent is None else (agent, agent.model) for agent in agents]
        robot = None if self._robot is None else self._native.agent(self._robot)
        self._robot_handle = None if robot is None else (robot, robot.model)

    def _targets(self, preferred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each person's speed (n,) [m/s] and target, (n, 2): :data:`TARGET_AHEAD` along its preferred velocity, or
        as far as one step of it, or where it stands, whichever first is inside the walkable area."""
        speeds, targets, near = heading_points(self.positions, preferred, self.scene.time_step, TARGET_AHEAD)
        inside = self._inside(np.concatenate((targets, near)))
        if not inside.all():
            first_inside(targets, near, self.positions, inside)
        return speeds, targets

    def _iterate(self, count: int) -> None:
        """``count`` JuPedSim iterations; a person outside the walkable area (where JuPedSim cannot route it) leaves
        first. (``Simulation.iterate(count)`` is this loop in Python over the compiled iteration, with its per-call
        work; this one calls the compiled iteration directly and looks at the agents only when one left.)"""
        iterate = self._native.iterate
        for _ in range(count):
            try:
                iterate()
            except RuntimeError:
                if not self._leave_area(self._rows()[:, :2]):
                    raise
                iterate()
            if self._changed:
                self._fetch()
                self._changed = False

    def _leave_area(self, positions: np.ndarray) -> bool:
        """Take the people at ``positions`` (n, 2) outside the walkable area out of the model; any?"""
        out = ~self._inside(positions)
        if not out.any():
            return False
        out &= ~self.frozen
        if not out.any():
            return False
        for i in np.flatnonzero(out).tolist():
            self._native.mark_agent_for_removal(self._ids[i])
        self.frozen |= out
        self._any_frozen = self._changed = True
        return True

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        speeds, targets = self._targets(np.array(preferred, dtype=np.float64).reshape(-1, 2))
        for handle, target, speed in zip(self._agents, targets.tolist(), speeds.tolist(), strict=True):
            if handle is not None:
                handle[0].target = target
                handle[1].desired_speed = speed
        path = self._robot_path(robot)
        if path is None:  # nothing changes between the sub-steps
            self._iterate(self.sub_steps)
        else:
            k, h = self.sub_steps, self.h
            (x0, y0), (x1, y1) = path
            for j in range(k):
                if self._robot_handle is not None:
                    agent, model = self._robot_handle
                    ax, ay = agent.position
                    f = (j + 1) / k
                    model.velocity = ((x0 + f * (x1 - x0) - ax) / h, (y0 + f * (y1 - y0) - ay) / h)
                self._iterate(1)
        state = self._rows()
        # pushed out in the last sub-step: marked now, removed as the next step's first iteration starts
        self._leave_area(state[:, :2])
        if self._any_frozen:
            frozen = self.frozen
            state[frozen, :2] = self.positions[frozen]  # where they were at the start of the step they left in
            state[frozen, 2:] = 0.0
        self.positions = state[:, :2].copy()
        return state[:, :2], state[:, 2:]

    def _rows(self) -> np.ndarray:
        """The people's (x, y, vx, vy) in the model, (n, 4) (zeros for one out of it)."""
        rows = [(*h[0].position, *h[1].velocity) if h is not None else (0.0, 0.0, 0.0, 0.0) for h in self._agents]
        return np.array(rows, dtype=np.float64).reshape(-1, 4)

    def _robot_path(self, robot: RobotAgent) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """The robot's straight path through the step, its agent added or removed as it is inside the area or not."""
        if not self.scene.robot_visible:
            return None
        start = robot.position
        end = robot.end_position
        if end is None:
            dt = self.scene.time_step
            end = (start[0] + robot.velocity[0] * dt, start[1] + robot.velocity[1] * dt)
        inside = bool(self._inside(np.array([start, end])).all())
        if not inside and self._robot is not None:
            self._native.mark_agent_for_removal(self._robot)
            self._robot = None
            self._robot_handle = None
            self._changed = True
        elif inside and self._robot is None:
            self._add_robot(start, robot.radius)
            self._fetch()
        return start, end


# every crowd model by its name (the env's crowd=); CROWD_SETTINGS has their settings under the same names
CROWD_MODELS: dict[str, type] = {
    "orca": OrcaCrowdModel,
    "linear": LinearCrowdModel,
    "social_force": SocialForceCrowdModel,
    "replay": ReplayCrowdModel,
}


def make_crowd(scene: SceneConfig) -> CrowdModel:
    """The crowd model ``scene.crowd`` with its settings ``scene.crowd_kwargs``."""
    return CROWD_MODELS[scene.crowd](scene)


__all__ = ["CROWD_MODELS", "CrowdModel", "LinearCrowdModel", "OrcaCrowdModel", "RecordedCrowd", "ReplayCrowdModel",
           "RobotAgent", "SocialForceCrowdModel", "Walls", "import_jupedsim", "make_crowd", "min_sub_steps"]
