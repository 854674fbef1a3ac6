"""Why episodes fail: each collision classified at its colliding step, each timeout by what the robot saw.

:func:`analyse_episodes` plays the runner's test episodes (any policy, env and crowd) through an
:class:`EpisodeRecorder`, one :class:`FailureRecord` each; :func:`summarize_failures` gives counts and shares with
Wilson 95 % intervals. The rules (parameters: :class:`FailureRules`):

* **Colliding step**: the last, from state k (whose observation the policy acted on) to k + 1. The person hit is the
  present one whose disc comes deepest into the robot's in it by the env's rule (straight-line centres,
  :func:`~sb3_crowdnav.sim.rewards.closest_approach`). A rack or wall hit (``"obstacle"``) gets its clearance and
  the avoidability tests only.
* **Closer**: with u the unit vector from the robot's centre to the person's at the start of the step, the robot
  closes at v_r·u, the person at -v_p·u (velocities: displacements in the step / Δt; a person appearing in it, their
  recorded one). The person's share of the sum above 0.5 + ``both_tolerance`` (0.1) is ``"person"``, below 0.5 -
  ``both_tolerance`` ``"robot"``, else ``"both"``; ``"none"`` when not closing or overlapping at the start (a replay).
* **Side**: the person's bearing from the robot's heading at the start of the step [deg, left positive]:
  ``"front"`` below the first of ``side_angles`` (45°), ``"behind"`` above the second (135°), else ``"side"``.
* **Sees the robot**: the person is one who sees the robot (``robot_visible``: the robot is one of the agents their
  crowd model avoids), drawn for the episode; a recording's people never do.
* **Seen**: the person's slot is set in the ``humans_mask`` the policy acted on (and no new person took it in the
  step); ``seen_for`` [s]: how long they had then been observed without a break.
* **Avoidable**: an action of the table, applied at the start of the step by the env's motion rule and limits
  (:func:`~sb3_crowdnav.sim.actions.apply_action`), ends it without a collision (people as above, racks and walls by
  the swept disc, :func:`~sb3_crowdnav.sim.geometry.swept_clearance`), everyone moving as recorded (nobody reacts).
* **Avoidable with warning**: the same from ``warning`` (1 s: 4 steps; or the reset) before the end of the colliding
  step through it, two plans per action: held every step; taken once, then the action of its speed nearest straight
  on (a unicycle keeps its new heading). A lower bound: another plan might avoid it.
* **Timeouts**: ``unseen_time`` [s], how long at the end no one was observed (in the ``humans_mask`` the policy
  acted on); ``nobody_in_view`` from ``blind_window`` (5 s) on; ``distance_left`` [m], straight to the goal.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import sys
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from sb3_crowdnav.evaluation.episode_log import EpisodeLog, EpisodeRecorder
from sb3_crowdnav.evaluation.metrics import wilson_interval
from sb3_crowdnav.evaluation.policy_spec import PolicySpec, is_spec
from sb3_crowdnav.evaluation.records import Trajectory
from sb3_crowdnav.evaluation.runner import DEFAULT_ENV_ID, TEST_SEED_OFFSET, eval_seeds, make_env, make_policy, run_episode
from sb3_crowdnav.sim.actions import action_table, apply_action, wrap_angle
from sb3_crowdnav.sim.geometry import swept_clearance
from sb3_crowdnav.sim.observation import Human, Robot
from sb3_crowdnav.sim.proximity import min_time_to_collision
from sb3_crowdnav.sim.rewards import closest_approach
from sb3_crowdnav.sim.validation import check_instance, check_int, check_positive, check_range

CLOSERS = ("robot", "person", "both", "none")
SIDES = ("front", "side", "behind")
NEAR_CLIP = 4.0  # [m] a clip keeps the people whose surface comes this close to the robot's centre


@dataclass(frozen=True)
class FailureRules:
    """The parameters of the module's rules (module docstring), each checked at construction."""

    both_tolerance: float = 0.1
    """Both close on each other when the person's share of the closing speed is within 0.5 ± this."""
    side_angles: tuple[float, float] = (45.0, 135.0)
    """[deg] A person's bearing below the first is in front, above the second behind, else at the side."""
    warning: float = 1.0
    """[s] The second avoidability test starts this long before the collision (whole steps, >= 1)."""
    blind_window: float = 5.0
    """[s] A timeout with no one observed for at least this long is "nobody in view"."""
    clip: float = 3.0
    """[s] The end of a collision episode kept for figures (:attr:`FailureRecord.clip`)."""

    def __post_init__(self) -> None:
        check_range("both_tolerance", self.both_tolerance, 0, 0.5, high_open=True)
        check_instance("side_angles", self.side_angles, tuple, "a (front, behind) pair [deg]")
        if len(self.side_angles) != 2:
            raise ValueError(f"side_angles must be a (front, behind) pair [deg], got {self.side_angles!r}")
        front, behind = self.side_angles
        check_range("side_angles[0]", front, 0, 180)
        check_range("side_angles[1]", behind, front, 180)
        for name in ("warning", "blind_window", "clip"):
            check_positive(name, getattr(self, name), " [s]")


@dataclass(frozen=True)
class CollisionAnalysis:
    """One collision at its colliding step (module docstring); person fields are empty ("", -1, nan) for an obstacle."""

    hit: str  # "human" or "obstacle"
    step: int  # the colliding step, from state ``step`` to ``step + 1``
    time: float  # [s] at the start of the colliding step
    robot_speed: float  # [m/s] during the colliding step
    avoidable: bool
    avoidable_with_warning: bool
    contact: tuple[float, float]  # [m] where the discs first touch (an obstacle: its point nearest the robot's end)
    clearance: float  # [m] an obstacle: the swept disc's clearance to racks and walls (< 0); a person: nan
    person: int = -1  # the person's slot
    closer: str = ""
    robot_closing: float = math.nan  # [m/s] v_r·u
    person_closing: float = math.nan  # [m/s] -v_p·u
    bearing: float = math.nan  # [deg] of the person from the robot's heading, positive to the left
    side: str = ""
    gap: float = math.nan  # [m] surface distance at the start of the step
    seen: bool = False
    seen_for: float = 0.0  # [s]
    sees_robot: bool = False  # the person sees the robot


@dataclass(frozen=True)
class TimeoutAnalysis:
    """One timeout (module docstring)."""

    unseen_time: float  # [s] no one observed over the end of the episode
    nobody_in_view: bool
    distance_left: float  # [m] to the goal, straight
    people_present: bool  # someone was present at the end


@dataclass(frozen=True)
class FailureRecord:
    """One episode's outcome and, for a collision or a timeout, its analysis; ``clip`` the end of a collision episode
    (``FailureRules.clip`` seconds, the people near the robot, for :func:`~sb3_crowdnav.evaluation.plots.plot_collisions`)."""

    seed: int
    outcome: str
    steps: int
    collision: CollisionAnalysis | None = None
    timeout: TimeoutAnalysis | None = None
    clip: Trajectory | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """Plain fields (no clip), e.g. for JSON."""
        parts = {"collision": self.collision, "timeout": self.timeout}
        return {"seed": self.seed, "outcome": self.outcome, "steps": self.steps,
                **{k: None if v is None else asdict(v) for k, v in parts.items()}}


# ---------------------------------------------------------------- the rules
def closer_of(robot_closing: float, person_closing: float, tolerance: float = 0.1) -> str:
    """Who closes on whom (module docstring) from the closing speeds [m/s] along the line of centres."""
    total = robot_closing + person_closing
    if not total > 0:
        return "none"
    share = person_closing / total
    return "person" if share > 0.5 + tolerance else "robot" if share < 0.5 - tolerance else "both"


def side_of(bearing: float, rules: FailureRules = FailureRules()) -> str:
    """``"front"``, ``"side"`` or ``"behind"`` of a bearing [deg] from the robot's heading."""
    front, behind = rules.side_angles
    return "front" if abs(bearing) < front else "behind" if abs(bearing) > behind else "side"


def _people_gaps(log: EpisodeLog, t: int, start: np.ndarray, end: np.ndarray,
                 radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(..., n) the smallest surface distance of the robot moving start -> end (..., 2) in step t to each person (inf:
    absent; below 0: the env's collision), and the people's centres (n, 2) at the start and end of the step as the env
    checks them (a person who took a slot in the step appears where they are, with no sweep from elsewhere)."""
    humans = log.trajectory.humans
    h1 = humans[t + 1, :, Human.POS]
    h0 = np.where(log.arrivals[t + 1][:, None], h1, humans[t, :, Human.POS])
    gaps = closest_approach(start[..., None, :], end[..., None, :], h0, h1) - radius - humans[t + 1, :, Human.RADIUS]
    return np.where(log.present[t + 1], gaps, np.inf), h0, h1


def _collides(log: EpisodeLog, t: int, start: np.ndarray, end: np.ndarray, radius: float) -> np.ndarray:
    """(P,) whether the robot moving start -> end (P, 2) in step t hits a person, a rack or a wall."""
    hit = (_people_gaps(log, t, start, end, radius)[0] < 0).any(axis=-1)
    if len(log.segments):
        hit |= swept_clearance(start, end, log.segments, np.ones(len(log.segments), dtype=bool)) < radius
    return hit


def _plans(speeds: np.ndarray, directions: np.ndarray, steps: int) -> np.ndarray:
    """(2 n_actions, steps) action indices: each action held; each taken once, then the action of the same speed
    nearest straight on (the same plans twice for one step)."""
    n = len(speeds)
    held = np.repeat(np.arange(n)[:, None], steps, axis=1)
    straight = np.array([min(np.flatnonzero(speeds == s), key=lambda a: abs(directions[a])) for s in speeds])
    turned = np.concatenate([np.arange(n)[:, None], np.repeat(straight[:, None], steps - 1, axis=1)], axis=1)
    return np.concatenate([held, turned])


def can_avoid(log: EpisodeLog, first: int, last: int) -> bool:
    """Whether a plan (:func:`_plans`) from the state at ``first`` goes through steps first..last without a collision,
    the people moving as recorded."""
    scene, robot = log.trajectory.scene, log.trajectory.robot[first]
    speeds, directions = action_table(scene.robot_v_pref, scene.rotation_range, scene.actions)
    plans = _plans(speeds, directions, last - first + 1)
    position, velocity = (np.repeat(robot[None, part], len(plans), axis=0) for part in (Robot.POS, Robot.VEL))
    heading = np.full(len(plans), robot[Robot.HEADING])
    hit = np.zeros(len(plans), dtype=bool)
    for i, t in enumerate(range(first, last + 1)):
        moved = apply_action(position, heading, robot[Robot.GOAL], speeds[plans[:, i]], directions[plans[:, i]],
                             scene.kinematics, scene.time_step, velocity=velocity,
                             max_acceleration=scene.max_acceleration, max_turn_rate=scene.max_turn_rate)
        hit |= _collides(log, t, position, moved.position, robot[Robot.RADIUS])
        position, heading, velocity = moved
    return not bool(hit.all())


def _seen_for(log: EpisodeLog, k: int, j: int) -> int:
    """Observations of slot j's person without a break up to state k, back to where they took the slot (0: unseen)."""
    unseen, arrived = np.flatnonzero(~log.seen[k::-1, j]), np.flatnonzero(log.arrivals[k::-1, j])
    return min(unseen[0] if len(unseen) else k + 1, arrived[0] + 1 if len(arrived) else k + 1)


def analyse_collision(log: EpisodeLog, rules: FailureRules = FailureRules(), hit: str = "human") -> CollisionAnalysis:
    """The analysis of a collision episode's last step (``hit``: the record's ``collision_with``)."""
    traj = log.trajectory
    dt = traj.scene.time_step
    k = len(log.actions) - 1
    r0, r1 = traj.robot[k], traj.robot[k + 1]
    p0, p1, radius = r0[Robot.POS], r1[Robot.POS], float(r0[Robot.RADIUS])
    warned = max(1, round(rules.warning / dt))
    common = dict(step=k, time=k * dt, robot_speed=float(np.linalg.norm(p1 - p0) / dt),
                  avoidable=can_avoid(log, k, k), avoidable_with_warning=can_avoid(log, max(0, k + 1 - warned), k))
    if hit == "obstacle":  # the contact: the point of the racks and walls nearest the robot's centre at the end
        clearance = float(swept_clearance(p0, p1, log.segments, np.ones(len(log.segments), dtype=bool))) - radius
        a, b = log.segments[:, :2], log.segments[:, 2:]
        along = np.clip(np.sum((p1 - a) * (b - a), axis=1) / np.maximum(np.sum((b - a) ** 2, axis=1), 1e-18), 0, 1)
        points = a + along[:, None] * (b - a)
        contact = points[np.argmin(np.linalg.norm(points - p1, axis=1))]
        return CollisionAnalysis(hit, contact=(float(contact[0]), float(contact[1])), clearance=clearance, **common)
    gaps, h0, h1 = _people_gaps(log, k, p0, p1, radius)
    j = int(np.argmin(gaps))
    h0, h1 = h0[j], h1[j]
    arrived = bool(log.arrivals[k + 1, j])
    offset = h0 - p0
    u = offset / max(float(np.linalg.norm(offset)), 1e-12)
    v_robot, v_motion = (p1 - p0) / dt, (h1 - h0) / dt
    v_person = traj.humans[k + 1, j, Human.VEL] if arrived else v_motion
    robot_closing, person_closing = float(v_robot @ u), float(-(v_person @ u))
    bearing = float(np.degrees(wrap_angle(math.atan2(offset[1], offset[0]) - r0[Robot.HEADING])))
    seen = bool(log.seen[k, j]) and not arrived
    person_radius = float(traj.humans[k + 1, j, Human.RADIUS])
    gap = float(np.linalg.norm(offset)) - radius - person_radius
    t = min_time_to_collision(*p0, *v_robot, radius, np.array([[*h0, *v_motion, person_radius]]), np.ones(1, bool), dt)
    centre, other = p0 + v_robot * t, h0 + v_motion * t
    contact = centre + (other - centre) * radius / (radius + person_radius)
    return CollisionAnalysis(
        hit, contact=(float(contact[0]), float(contact[1])), clearance=math.nan, person=j,
        closer=closer_of(robot_closing, person_closing, rules.both_tolerance) if gap >= 0 else "none", gap=gap,
        robot_closing=robot_closing, person_closing=person_closing, bearing=bearing, side=side_of(bearing, rules), seen=seen,
        seen_for=_seen_for(log, k, j) * dt if seen else 0.0, sees_robot=bool(log.sees_robot[j]), **common)


def analyse_timeout(log: EpisodeLog, rules: FailureRules = FailureRules()) -> TimeoutAnalysis:
    """The analysis of a timeout."""
    anyone = log.seen[:-1].any(axis=1)  # the observations the policy acted on
    trailing = len(anyone) - 1 - int(np.flatnonzero(anyone)[-1]) if anyone.any() else len(anyone)
    unseen = trailing * log.trajectory.scene.time_step
    end = log.trajectory.robot[-1]
    return TimeoutAnalysis(unseen, unseen >= rules.blind_window - 1e-9,
                           float(np.linalg.norm(end[Robot.GOAL] - end[Robot.POS])), bool(log.present[-1].any()))


def collision_clip(log: EpisodeLog, seconds: float = 3.0) -> Trajectory:
    """The last ``seconds`` of an episode with the people who are present at its end and come within
    :data:`NEAR_CLIP` of the robot; a person who appeared in the clip stands where they appeared before."""
    traj = log.trajectory
    first = max(0, len(traj.robot) - 1 - round(seconds / traj.scene.time_step))
    robot, humans = traj.robot[first:], traj.humans[first:].copy()
    present, arrivals = log.present[first:], log.arrivals[first:]
    distance = np.linalg.norm(humans[..., Human.POS] - robot[:, None, Robot.POS], axis=-1) - humans[..., Human.RADIUS]
    keep = np.flatnonzero(present[-1] & (np.where(present, distance, np.inf).min(axis=0) < NEAR_CLIP))
    for j in keep.tolist():
        new = np.flatnonzero(~present[:, j] | arrivals[:, j])
        since = int(new[-1]) + (0 if arrivals[new[-1], j] and present[new[-1], j] else 1) if len(new) else 0
        humans[:since, j] = humans[since, j]
    return Trajectory(robot=robot, humans=humans[:, keep], human_goals=np.full((len(keep), 2), np.nan),
                      scene=traj.scene, obstacles=traj.obstacles)


def analyse_episode(env: EpisodeRecorder, policy: Any, seed: int, rules: FailureRules = FailureRules(),
                    deterministic: bool = True) -> FailureRecord:
    """Play one episode of ``env`` (wrapped in an :class:`EpisodeRecorder`) with ``policy`` and analyse it."""
    record = run_episode(env, policy, seed, deterministic, keep_trajectory=True)
    log = env.log(record.trajectory)
    head = dict(seed=record.seed, outcome=record.outcome, steps=record.steps)
    if record.outcome == "collision":
        return FailureRecord(**head, collision=analyse_collision(log, rules, record.collision_with),
                             clip=collision_clip(log, rules.clip))
    if record.outcome == "timeout":
        return FailureRecord(**head, timeout=analyse_timeout(log, rules))
    return FailureRecord(**head)


# ---------------------------------------------------------------- many episodes, worker processes
_WORKER: dict[str, Any] = {}


def _init_worker(spec: PolicySpec, env_id: str, env_kwargs: dict[str, Any], rules: FailureRules,
                 deterministic: bool) -> None:
    env = EpisodeRecorder(make_env(env_id, env_kwargs))
    _WORKER.update(env=env, policy=make_policy(spec, env, allow_env_mismatch=True),  # the parent checked it
                   rules=rules, deterministic=deterministic)
    if "torch" in sys.modules:  # one thread per worker, as the runner's (never import torch just for this)
        sys.modules["torch"].set_num_threads(1)


def _worker_episode(seed: int) -> FailureRecord:
    return analyse_episode(_WORKER["env"], _WORKER["policy"], seed, _WORKER["rules"], _WORKER["deterministic"])


def analyse_episodes(policy: Any, n_episodes: int | None = None, env_kwargs: Mapping[str, Any] | None = None, *,
                     env_id: str = DEFAULT_ENV_ID, seeds: Iterable[int] | None = None,
                     seed_offset: int = TEST_SEED_OFFSET, workers: int = 1, rules: FailureRules = FailureRules(),
                     deterministic: bool = True, allow_env_mismatch: bool = False) -> list[FailureRecord]:
    """One :class:`FailureRecord` per test episode, in seed order, the same for any number of ``workers`` (``spawn``
    processes): the seeds, policies (a spec; an object with ``predict`` with one worker) and checks of
    :func:`~sb3_crowdnav.evaluation.runner.run_episodes`; ``rules``: the parameters of the module's rules."""
    if seeds is None:
        check_int("n_episodes", n_episodes, 1)
        seeds = eval_seeds(int(n_episodes), seed_offset)
    seeds = [int(s) for s in seeds]
    check_int("workers", workers, 1)
    if is_spec(policy):
        policy = PolicySpec.parse(policy)
    elif workers > 1:
        raise ValueError(f"workers > 1 needs a policy spec, not a {type(policy).__name__} object")
    env_kwargs = dict(env_kwargs or {})
    env = EpisodeRecorder(make_env(env_id, env_kwargs))
    try:  # a bad policy or env fails here, before any worker starts
        acting = make_policy(policy, env, allow_env_mismatch)
        if workers == 1 or len(seeds) == 1:
            return [analyse_episode(env, acting, s, rules, deterministic) for s in seeds]
    finally:
        env.close()
    chunk = max(1, min(8, len(seeds) // (workers * 8)))
    with mp.get_context("spawn").Pool(min(workers, len(seeds)), initializer=_init_worker,
                                      initargs=(policy, env_id, env_kwargs, rules, deterministic)) as pool:
        return list(pool.imap(_worker_episode, seeds, chunksize=chunk))


# ---------------------------------------------------------------- the summary
@dataclass(frozen=True)
class Share:
    """``count`` of ``total``: ``value`` with its Wilson 95 % interval ``low``-``high`` (``nan`` when ``total`` is 0)."""

    count: int
    total: int
    value: float
    low: float
    high: float

    @classmethod
    def of(cls, count: int, total: int) -> Share:
        return cls(int(count), int(total), count / total if total else math.nan, *wilson_interval(int(count), int(total)))


@dataclass(frozen=True)
class FailureSummary:
    """Counts and shares of a policy's failures.

    ``table[closer][side]`` counts the collisions with people; ``shares`` holds, each with its Wilson 95 % interval:
    ``collision`` and ``timeout`` of the episodes; ``person_faster`` (closing faster than the robot, not overlapping),
    ``person``, ``behind``, ``seen``, ``seen_warned`` (seen for at least ``warning``), ``sees_robot``, ``avoidable`` and
    ``avoidable_with_warning`` of the collisions with people; ``obstacle_avoidable`` and
    ``obstacle_avoidable_with_warning`` of those with racks and walls; ``nobody_in_view`` of the timeouts.
    """

    episodes: int
    collisions: int
    obstacle_collisions: int
    timeouts: int
    table: dict[str, dict[str, int]]
    shares: dict[str, Share]
    obstacle_clearance: float  # [m] mean over the obstacle collisions (nan: none)
    distance_left: float  # [m] mean over the timeouts (nan: none)
    robot_speed: float = math.nan  # [m/s] median over the collisions with people of the robot's in the colliding step


def summarize_failures(records: Sequence[FailureRecord], rules: FailureRules = FailureRules()) -> FailureSummary:
    """The :class:`FailureSummary` of one policy's records."""
    people = [r.collision for r in records if r.collision is not None and r.collision.hit == "human"]
    racks = [r.collision for r in records if r.collision is not None and r.collision.hit == "obstacle"]
    timeouts = [r.timeout for r in records if r.timeout is not None]
    cells = Counter((c.closer, c.side) for c in people)
    n, m, n_people = len(records), len(racks), len(people)
    shares = {
        "collision": Share.of(n_people + m, n),
        "timeout": Share.of(len(timeouts), n),
        "person_faster": Share.of(sum(c.person_closing > c.robot_closing and c.gap >= 0 for c in people), n_people),
        "person": Share.of(sum(c.closer == "person" for c in people), n_people),
        "behind": Share.of(sum(c.side == "behind" for c in people), n_people),
        "seen": Share.of(sum(c.seen for c in people), n_people),
        "seen_warned": Share.of(sum(c.seen_for >= rules.warning - 1e-9 for c in people), n_people),
        "sees_robot": Share.of(sum(c.sees_robot for c in people), n_people),
        "avoidable": Share.of(sum(c.avoidable for c in people), n_people),
        "avoidable_with_warning": Share.of(sum(c.avoidable_with_warning for c in people), n_people),
        "obstacle_avoidable": Share.of(sum(c.avoidable for c in racks), m),
        "obstacle_avoidable_with_warning": Share.of(sum(c.avoidable_with_warning for c in racks), m),
        "nobody_in_view": Share.of(sum(t.nobody_in_view for t in timeouts), len(timeouts)),
    }
    table = {closer: {side: cells[(closer, side)] for side in SIDES} for closer in CLOSERS}
    clearance = float(np.mean([c.clearance for c in racks])) if racks else math.nan
    left = float(np.mean([t.distance_left for t in timeouts])) if timeouts else math.nan
    speed = float(np.median([c.robot_speed for c in people])) if people else math.nan
    return FailureSummary(n, n_people, m, len(timeouts), table, shares, clearance, left, speed)


__all__ = [
    "CLOSERS", "SIDES", "CollisionAnalysis", "FailureRecord", "FailureRules",
    "FailureSummary", "Share", "TimeoutAnalysis", "analyse_collision", "analyse_episode", "analyse_episodes",
    "analyse_timeout", "can_avoid", "closer_of", "collision_clip", "side_of", "summarize_failures",
]
