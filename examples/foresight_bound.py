"""How far perfect foresight of the people takes a value model's lookahead: a research probe, not a policy.

    python examples/foresight_bound.py --policy pretrained:apg_warehouse --episodes 200 --foresight next
    python examples/foresight_bound.py --policy pretrained:apg_warehouse --episodes 200 --foresight braking \\
        --steps 6 --charge-standing
    python examples/foresight_bound.py --policy pretrained:apg_warehouse --episodes 200 --foresight plans --steps 6

The model plays the validation episodes (seeds 2,000,000 + i by default) of ``--env`` (default the warehouse) and,
before each decision, is told where the people it observes will really be:

* ``--foresight none``: nothing (the model as it is, the reference);
* ``--foresight next``: the observed people's newest velocities are replaced by those of their real next step, so
  the lookahead's constant-velocity step puts each of them exactly where the env will (the rest of the search is
  unchanged);
* ``--foresight braking``: the lookahead's stopping check (the model must have one) also charges a collision to
  every action after which the robot, braking to a stand and then standing, comes within the radii sum of an
  observed person's real path over the next ``--steps`` steps (the people as they walk while the robot brakes);
  contact while the robot stands is charged only with ``--charge-standing`` (the stopping check's own rule leaves
  it out). The charges are the check's: where every action is charged, none is.
* ``--foresight plans``: the stopping check's charge for people replaced by a planner's with the same foresight:
  an action is charged when every one of its continuations over the next ``--steps`` steps (holding it; its speed
  straight on; the stop) meets an observed person's real path (the robot standing included) or an observed rack or
  wall segment. It asks of an action only that some short plan after it stays clear, where the stopping check asks
  that braking does (the check's charge for racks, a braking path into one, stays).
* ``--foresight predicted-plans``: the same planner's charge without foresight: the observed people's paths
  predicted at constant velocity (the lookahead's own prediction), for comparison.

The real future comes from a second env: reset from the episode's seed, the episode's actions replayed, then
stepped once more (``next``), or on with the stop command (``braking``, ``plans``: the people's paths are those of
a robot that brakes, the best guess for the other plans). An ORCA person reads the robot's state at
the start of a step, so their next step does not depend on the robot's action in it, and the foresight is exact;
the probe checks this at every step and stops with an error in a crowd where it is not (social force, whose people
feel the robot's move through the step). Prints success / collisions with people / with racks or walls / timeouts,
as episodes. Bad input exits with status 2 and one line, before any episode.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Any

import numpy as np

from sb3_crowdnav.apg_value import propagation
from sb3_crowdnav.cli.common import (
    Parser,
    UsageError,
    check_env,
    env_kwargs_from_args,
    env_options,
    nonneg_int,
    positive_int,
    single_crowd,
)
from sb3_crowdnav.evaluation.runner import make_env, make_policy, with_lookahead
from sb3_crowdnav.sim.actions import N_ACTIONS, N_DIRECTIONS, STOP_ACTION, apply_action
from sb3_crowdnav.sim.geometry import swept_clearance
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, ObservationSchema, Robot
from sb3_crowdnav.sim.rewards import closest_approach
from sb3_crowdnav.training.callbacks import VALIDATION_SEED_OFFSET

PLANNERS = ("plans", "predicted-plans")  # a planner's charge on the people's paths
CHECKED = ("braking", *PLANNERS)  # through the lookahead's stopping check
FORESIGHTS = ("none", "next", *CHECKED)


class Foresight:
    """The people's real positions and velocities ahead of an episode's current step, from a replay of its actions.

    :param env: a second env of the same id and options as the one played
    :param seed: the episode's seed
    """

    def __init__(self, env: Any, seed: int) -> None:
        self.env = env
        self.seed = int(seed)
        self.actions: list[int] = []  # the episode's actions so far

    def ahead(self, steps: int, then: int) -> np.ndarray:
        """(steps, n, 5): the people's rows of the next ``steps`` steps (position, velocity, radius), the first of the
        step about to be taken (whatever the robot does in it), the others with the robot doing ``then``; an episode
        that ends early repeats its last row."""
        env = self.env
        env.reset(seed=self.seed)
        for action in self.actions:
            env.step(action)
        sim = env.unwrapped.sim
        rows = []
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(then)
            rows.append(sim.history[-1, : sim.num_humans].copy())
            if terminated or truncated:
                break
        rows += [rows[-1]] * (steps - len(rows))
        return np.stack(rows)


def with_next_velocities(obs: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    """``obs`` with the observed people's newest velocities replaced by those of ``rows`` (n, 5), their next step."""
    told = {**obs, "humans": obs["humans"].copy()}
    n = rows.shape[0]
    seen = obs["humans_mask"][:n] > 0.5
    _humans(told)[-1, :n][seen, Human.VEL] = rows[seen][:, Human.VEL]
    return told


@contextmanager
def braking_foresight(pending: dict[str, Any], charge_standing: bool) -> Iterator[None]:
    """Within the block, the stopping check of a one-observation lookahead also charges the actions whose braking path
    meets the people's real paths ``pending["paths"]`` ((steps, n, 2), set before each decision and used once), or,
    given ``pending["doomed"]`` ((A,) bool, :func:`doomed_actions`), charges those instead of its own prediction."""
    check = propagation.braking_hits

    def hits(path, radius, starts, velocities, human_radius, mask, time_step):
        doomed = pending.get("doomed")
        pending["doomed"] = None  # (used once)
        if doomed is not None and path.shape[1] == 1:
            return doomed[None, :].copy()
        hit = check(path, radius, starts, velocities, human_radius, mask, time_step)
        paths = pending["paths"]
        pending["paths"] = None
        if paths is None or path.shape[1] != 1:  # a deeper step of the search: the check as it is
            return hit
        if path.shape[0] < paths.shape[0]:  # the robot stands at the braking's end
            path = np.concatenate([path, np.repeat(path[-1:], paths.shape[0] - path.shape[0], axis=0)])
        n = paths.shape[1]
        reach = human_radius[0, :n] + float(np.asarray(radius).reshape(-1)[0])
        observed = np.asarray(mask, dtype=bool)[0, :n]
        extra = _crossings(path[: paths.shape[0]], paths[:, observed], reach[observed], moving_only=not charge_standing)
        return hit | extra

    propagation.braking_hits = hits
    try:
        yield
    finally:
        propagation.braking_hits = check


def _crossings(path: np.ndarray, people: np.ndarray, reach: np.ndarray, moving_only: bool = False) -> np.ndarray:
    """(...) bool: the robot's ``path`` (K + 1, ..., 2) comes within ``reach`` (n,) of the people's ``people``
    (K + 1, n, 2) in some step (the closest approach of the two straight motions of each step); with
    ``moving_only``, only in the steps that move the robot (the stopping check's rule)."""
    hit = np.zeros(path.shape[1:-1], dtype=bool)
    for j in range(path.shape[0] - 1):
        off0 = path[j][..., None, :] - people[j]
        off1 = path[j + 1][..., None, :] - people[j + 1]
        origin = np.zeros_like(off0)
        near = (closest_approach(off0, off1, origin, origin) < reach).any(axis=-1)
        if moving_only:
            near &= np.sum((path[j + 1] - path[j]) ** 2, axis=-1) > propagation.STANDING_STEP ** 2
        hit |= near
    return hit


def _humans(obs: dict[str, np.ndarray]) -> np.ndarray:
    """(T, M, 5): a view of the observation's people (``humans`` holds T * M * 5 values, M the mask's size)."""
    mask = obs["humans_mask"]
    humans = obs["humans"]
    return ObservationSchema(humans.size // (mask.size * HUMAN_DIM), mask.size).humans_view(humans[None])[0]


def doomed_actions(world: Any, obs: dict[str, np.ndarray], people: np.ndarray, radii: np.ndarray,
                   steps: int) -> np.ndarray:
    """(A,) bool: the actions after which every plan over ``steps`` steps (holding the action; the action's speed
    straight on; the stop) meets an observed person's real path or an observed rack or wall segment.

    :param world: the model's :class:`~sb3_crowdnav.sim.world.World`
    :param people: (steps + 1, n, 2) the people's positions now and over the next ``steps`` steps
    :param radii: (n,) their radii [m]
    """
    robot = np.asarray(obs["robot"], dtype=np.float64)
    fractions, directions = world.action_table(1.0)
    speeds = robot[Robot.V_PREF] * fractions
    n_actions = speeds.size
    n = people.shape[1]
    straight = np.where(np.arange(n_actions) < N_ACTIONS, np.arange(n_actions) - np.arange(n_actions) % N_DIRECTIONS,
                        np.arange(n_actions))  # the action of the same speed, direction 0 (the stop stays the stop)
    stop = int(np.flatnonzero(speeds == 0)[0]) if (speeds == 0).any() else int(np.argmin(speeds))
    plans = np.stack([np.arange(n_actions), straight, np.full(n_actions, stop)], axis=1)  # (A, 3) the later actions
    position = np.broadcast_to(robot[Robot.POS], (n_actions, 3, 2))
    heading = np.broadcast_to(robot[Robot.HEADING], (n_actions, 3))
    velocity = np.broadcast_to(robot[Robot.VEL], (n_actions, 3, 2))
    goal = np.broadcast_to(robot[Robot.GOAL], (n_actions, 3, 2))
    path = [position]
    for j in range(steps):
        chosen = np.broadcast_to(np.arange(n_actions)[:, None], (n_actions, 3)) if j == 0 else plans
        position, heading, velocity = apply_action(position, heading, goal, speeds[chosen], directions[chosen],
                                                   world.kinematics, world.time_step, velocity,
                                                   world.max_acceleration, world.max_turn_rate)
        path.append(position)
    path = np.stack(path)  # (steps + 1, A, 3, 2)
    observed = np.asarray(obs["humans_mask"][:n]) > 0.5
    hit = _crossings(path, people[:, observed], radii[observed] + robot[Robot.RADIUS])
    if "obstacles" in obs:
        segments = np.asarray(obs["obstacles"], dtype=np.float64).reshape(-1, 4)
        present = np.asarray(obs["obstacles_mask"]) > 0.5
        for j in range(steps):
            hit |= swept_clearance(path[j], path[j + 1], segments, present) < robot[Robot.RADIUS]
    return hit.all(axis=1)


def play(policy: Any, env: Any, twin: Any, seeds: list[int], foresight: str, steps: int,
         pending: dict[str, Any]) -> Counter:
    """The episodes of ``seeds``; their outcomes (success, people, obstacles, timeout) and, with a planner's charge,
    ``cornered``: the collisions with a decision among their last ``steps`` at which every action was charged (no plan
    of the set clear). ``pending`` is the dict of :func:`braking_foresight`."""
    outcomes: Counter = Counter()
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        future = Foresight(twin, seed)
        no_plan: list[bool] = []  # per decision, with a planner's charge: every action charged
        while True:
            expected = None
            if foresight == "next":
                expected = future.ahead(1, 0)[0]
                obs = with_next_velocities(obs, expected)
            elif foresight == "braking":
                rows = future.ahead(steps + 1, STOP_ACTION)
                expected = rows[0]
                pending["paths"] = rows[:, :, Human.POS]
            elif foresight == "predicted-plans":
                sim = env.unwrapped.sim
                # (n, 5) as observed (doomed_actions reads the observed)
                latest = _humans(obs)[-1, : sim.num_humans].astype(np.float64)
                ahead = np.arange(steps + 1)[:, None, None] * sim.scene.time_step
                pending["doomed"] = doomed_actions(policy.policy.world, obs,
                                                   latest[None, :, Human.POS] + ahead * latest[None, :, Human.VEL],
                                                   latest[:, Human.RADIUS], steps)
            elif foresight == "plans":
                rows = future.ahead(steps, STOP_ACTION)
                sim = env.unwrapped.sim
                now = sim.history[-1, : sim.num_humans, Human.POS][None]
                expected = rows[0]
                pending["doomed"] = doomed_actions(policy.policy.world, obs, np.concatenate([now, rows[:, :, Human.POS]]),
                                                   rows[0, :, Human.RADIUS], steps)
            if pending.get("doomed") is not None:
                no_plan.append(bool(pending["doomed"].all()))
            action = int(np.asarray(policy.predict(obs, deterministic=True)[0]).reshape(-1)[0])
            future.actions.append(action)
            obs, _, terminated, truncated, info = env.step(action)
            if expected is not None:
                sim = env.unwrapped.sim
                if not np.array_equal(sim.history[-1, : sim.num_humans, Human.POS], expected[:, Human.POS]):
                    raise RuntimeError(f"seed {seed}, step {len(future.actions)}: the people's step depends on the "
                                       "robot's action in this env; foresight by replay needs a crowd that reads the "
                                       "robot's state at the start of the step (ORCA)")
            if terminated or truncated:
                break
        outcome = info["outcome"]
        if outcome == "collision":
            outcome = "obstacles" if info.get("collision_with", "human") != "human" else "people"
            outcomes["cornered"] += any(no_plan[-steps:])
        outcomes[outcome] += 1
    return outcomes


def parse(argv: list[str] | None) -> tuple[argparse.Namespace, str, dict[str, Any]]:
    p = Parser(prog="foresight_bound.py", description=__doc__, parents=[env_options()],
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default="pretrained:apg_warehouse", metavar="SPEC",
                   help="a value model's spec, as for sb3-crowdnav evaluate (default: pretrained:apg_warehouse)")
    p.add_argument("--foresight", choices=FORESIGHTS, default="next", help="what the model is told (default: next)")
    p.add_argument("--steps", type=positive_int,
                   help="--foresight braking, plans: steps of the people's real paths (default: 6)")
    p.add_argument("--charge-standing", action="store_true",
                   help="--foresight braking: charge contact while the robot stands too")
    p.add_argument("--pedestrian-model", choices=propagation.PropagationModel.PEDESTRIAN_MODELS,
                   help="the lookahead's prediction of the people (default: the model's)")
    p.add_argument("--episodes", type=positive_int, default=200, help="episodes (default: 200)")
    p.add_argument("--seed-offset", type=nonneg_int, default=VALIDATION_SEED_OFFSET,
                   help=f"seed of the first episode (default: {VALIDATION_SEED_OFFSET:,}, the validation seeds)")
    args = p.parse_args(argv)
    env_id = args.env or "CrowdNavWarehouse-v0"
    steps_given = args.steps
    args.steps = args.steps or 6
    try:
        if args.foresight not in CHECKED and (steps_given is not None or args.charge_standing):
            raise UsageError("--steps and --charge-standing belong to --foresight braking (--steps also to plans)")
        if args.foresight in PLANNERS and args.charge_standing:
            raise UsageError("--charge-standing belongs to --foresight braking (plans charge contact while standing)")
        kwargs = env_kwargs_from_args(args)
        check_env(env_id, kwargs, single_crowd(args))
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    return args, env_id, kwargs


def main(argv: list[str] | None = None) -> None:
    args, env_id, kwargs = parse(argv)
    from sb3_crowdnav.nn import configure_cpu

    configure_cpu(num_threads=1)
    env = make_env(env_id, kwargs)
    twin = make_env(env_id, kwargs)  # the replay's env
    try:
        policy = make_policy(args.policy, env.unwrapped)
        lookahead = getattr(getattr(policy, "policy", None), "propagation", None)
        if lookahead is None:
            raise ValueError("it has no lookahead to tell the future to (a value model's spec is needed)")
        if args.foresight in CHECKED and not lookahead.stopping_check:
            raise ValueError(f"--foresight {args.foresight} needs a model with the stopping check; it has none")
    except (TypeError, ValueError) as exc:
        print(f"foresight_bound.py: error: --policy {args.policy!r}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    if args.pedestrian_model:
        policy = with_lookahead(policy, {"pedestrian_model": args.pedestrian_model})
    seeds = list(range(args.seed_offset, args.seed_offset + args.episodes))
    pending: dict[str, Any] = {"paths": None}
    with braking_foresight(pending, args.charge_standing) if args.foresight in CHECKED else nullcontext():
        try:
            outcomes = play(policy, env, twin, seeds, args.foresight, args.steps, pending)
        except RuntimeError as exc:
            raise SystemExit(f"foresight_bound.py: error: {exc}") from None
    told = args.foresight
    if told in PLANNERS:
        told += f" ({args.steps} steps)"
    if told == "braking":
        told += f" ({args.steps} steps{', standing charged' if args.charge_standing else ''})"
    if args.pedestrian_model:
        told += f", pedestrian model {args.pedestrian_model}"
    world = f"{env_id} {kwargs}" if kwargs else env_id
    print(f"{args.policy}, foresight {told}, {world}, {args.episodes} episodes from seed {args.seed_offset:,}: "
          f"success / people / obstacles / timeouts {outcomes['success']} / {outcomes['people']} / "
          f"{outcomes['obstacles']} / {outcomes['timeout']}"
          + (f"; collisions with no clear plan in their last {args.steps} decisions: {outcomes['cornered']}"
             if args.foresight in PLANNERS else ""))


if __name__ == "__main__":
    main()
