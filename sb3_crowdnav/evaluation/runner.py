"""One runner for every policy with SB3's ``predict(observation, state, episode_start, deterministic)``.

Test seeds
----------
Episode ``i`` of an evaluation is ``env.reset(seed=TEST_SEED_OFFSET + i)`` with
``TEST_SEED_OFFSET = 1_000_000``. Training (``make_vec_env(..., seed=s)``, ``sb3-crowdnav train
--seed s``) uses small seeds ``s, s + 1, ...`` for its envs, so the test episodes are disjoint from
the episodes a model was trained on. An episode depends only on its seed (the env is seeded
through ``reset(seed=...)`` and a stochastic policy is re-seeded per episode through
:meth:`RandomPolicy.seed_episode`, or an SB3 model through its ``set_random_seed``), so records do
not depend on the order of the episodes or on how they are split across worker processes.

Policies are given either as an object with ``predict`` (one process) or as a picklable **spec**
(any number of processes) in the grammar of :class:`~sb3_crowdnav.evaluation.policy_spec.PolicySpec`:
``"orca"``, ``"orca-constrained"``, ``"random"`` / ``"random:SEED"``, ``"pretrained:NAME"`` or the
path of a saved model ``.zip`` (APGValue, DQN, PPO, ... detected by :func:`~sb3_crowdnav.models.load_model`).
"""

from __future__ import annotations

import multiprocessing as mp
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

import sb3_crowdnav  # noqa: F401  (registers the envs, also in spawned workers)
from sb3_crowdnav.evaluation.policy_spec import PolicySpec, is_spec
from sb3_crowdnav.evaluation.records import RECORD_FIELDS, EpisodeRecord, Trajectory
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.validation import check_int

TEST_SEED_OFFSET = 1_000_000
"""Seed of the first test episode; episode ``i`` uses ``TEST_SEED_OFFSET + i``."""

DEFAULT_ENV_ID = "CrowdNav-v0"


class RandomPolicy:
    """Uniformly random actions, reproducible per episode.

    The runner calls :meth:`seed_episode` with the episode's seed at every reset, so the actions
    of an episode depend only on ``(seed, episode seed)``, not on the order of the episodes.

    :param action_space: a ``gymnasium.spaces.Discrete`` space or its number of actions
    :param seed: base seed, an int >= 0 (NumPy's seed sequences refuse negative entries)
    """

    def __init__(self, action_space: gym.spaces.Discrete | int = 80, seed: int = 0) -> None:
        n = action_space.n if isinstance(action_space, gym.spaces.Discrete) else action_space
        check_int("action_space (a Discrete space or its number of actions)", n, 1)
        check_int("seed", seed, 0)
        self.n = int(n)
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)

    def seed_episode(self, episode_seed: int) -> None:
        self.rng = np.random.default_rng([self.seed, int(episode_seed)])

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """``(actions, None)``; batched when ``observation["robot"]`` is 2-D (a VecEnv)."""
        robot = np.asarray(observation["robot"])
        if robot.ndim == 1:
            return np.array(self.rng.integers(self.n)), None
        return self.rng.integers(self.n, size=robot.shape[0]), None


def policy_label(spec: Any) -> str:
    """A short table label: a spec's :attr:`PolicySpec.label` (``ORCA``, ``Random``, ...), an object's class name."""
    return PolicySpec.parse(spec).label if is_spec(spec) else type(spec).__name__


def make_policy(spec: Any, env: gym.Env | None = None, allow_env_mismatch: bool = False,
                protective_field: Any = None, lookahead: Mapping[str, Any] | None = None) -> Any:
    """Turn a spec (see :class:`PolicySpec`) into an object with ``predict``; objects with ``predict`` pass through.

    ``"orca"`` → :class:`~sb3_crowdnav.sim.orca.OrcaPolicy` built from ``env`` (nearest-action
    mapping, the paper's ORCA row); ``"orca-constrained"`` → the same with the constrained mapping;
    ``"random"`` or ``"random:SEED"`` → :class:`RandomPolicy`; ``"pretrained:NAME"`` → a model
    shipped with the package (:func:`sb3_crowdnav.pretrained`); a file ``.onnx`` → an exported graph run by
    :class:`~sb3_crowdnav.deploy.OnnxPolicy` (one of a MaskablePPO model with the env's wall masks); any other
    string → a saved model loaded with :func:`~sb3_crowdnav.models.load_model` (a MaskablePPO one acts with its wall masks:
    :class:`~sb3_crowdnav.apg_value.action_masks.WallMaskedPolicy`). A model trained in another world than ``env``
    (time step, kinematics, rotation range) is refused unless ``allow_env_mismatch``. A
    :class:`~sb3_crowdnav.safety.ProtectiveField` wraps the policy in a
    :class:`~sb3_crowdnav.safety.ProtectedPolicy` (it needs ``env``). ``lookahead`` sets a value model's lookahead
    (:func:`with_lookahead`).
    """
    policy = _make_policy(spec, env, allow_env_mismatch)
    if lookahead:
        policy = with_lookahead(policy, lookahead)
    if protective_field is None:
        return policy
    from sb3_crowdnav.safety import ProtectedPolicy

    if env is None:
        raise ValueError("protective_field needs the env the policy acts in (its action table)")
    return ProtectedPolicy(policy, protective_field, env)


LOOKAHEAD_KEYS = ("pedestrian_model", "stopping_check", "planning_depth", "planning_width", "cap_values")


def with_lookahead(policy: Any, lookahead: Mapping[str, Any]) -> Any:
    """``policy`` (a value model: APGValue) with its lookahead's ``pedestrian_model``, ``stopping_check``,
    ``planning_depth``, ``planning_width`` and/or ``cap_values`` set
    (:class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy`'s setters; V unchanged). A depth of 1 without a width
    also drops the model's width (a one-step lookahead has none).
    ``ValueError`` for another policy or another key; the setters refuse a value the model's world does not take (a
    stopping check without limits), a depth that is not an int >= 1 or a width with a depth of 1."""
    unknown = sorted(set(lookahead) - set(LOOKAHEAD_KEYS))
    if unknown:
        raise ValueError(f"lookahead takes {LOOKAHEAD_KEYS}, got {unknown}")
    value_policy = getattr(policy, "policy", None)
    if not hasattr(value_policy, "set_pedestrian_model"):
        raise ValueError(f"{' and '.join(lookahead)} set a value model's lookahead (APGValue); "
                         f"{policy_label(policy)} has none")
    if "pedestrian_model" in lookahead:
        value_policy.set_pedestrian_model(lookahead["pedestrian_model"])
    if "stopping_check" in lookahead:
        value_policy.set_stopping_check(bool(lookahead["stopping_check"]))
    if "cap_values" in lookahead:
        value_policy.set_cap_values(lookahead["cap_values"])
    if "planning_depth" in lookahead or "planning_width" in lookahead:
        depth = lookahead.get("planning_depth", value_policy.planning_depth)
        kept = value_policy.planning_width if depth != 1 else None
        value_policy.set_planning(depth, lookahead.get("planning_width", kept))
    return policy


def _make_policy(spec: Any, env: gym.Env | None, allow_env_mismatch: bool) -> Any:
    if not is_spec(spec):
        if not hasattr(spec, "predict"):
            raise TypeError(f"policy must be a spec string or have predict(observation, deterministic=...), "
                            f"got {type(spec).__name__}")
        if env is not None and not allow_env_mismatch:
            check_world(spec, env)
        return spec
    parsed = PolicySpec.parse(spec)
    if parsed.kind in ("orca", "orca-constrained"):
        from sb3_crowdnav.sim.orca import OrcaPolicy

        mapping = "constrained" if parsed.kind == "orca-constrained" else "nearest"
        return OrcaPolicy.from_env(env, mapping=mapping) if env is not None else OrcaPolicy(mapping=mapping)
    if parsed.kind == "random":
        return RandomPolicy(env.action_space if env is not None else 80, seed=parsed.seed)
    if parsed.is_onnx:  # an exported graph: it checks the env's shapes and world itself
        from sb3_crowdnav.deploy import OnnxPolicy

        graph = OnnxPolicy(str(parsed.argument), env, allow_env_mismatch=allow_env_mismatch)
        if graph.metadata.kind != "masked_logits" or env is None:
            return graph
        from sb3_crowdnav.apg_value.action_masks import WallMaskedPolicy
        from sb3_crowdnav.serialization import world_of

        return WallMaskedPolicy(graph, world_of(env))  # a MaskablePPO graph acts with the env's wall masks, as its model
    from sb3_crowdnav.models import check_pretrained, load_model

    path = str(check_pretrained(parsed.argument)) if parsed.kind == "pretrained" else str(parsed.argument)
    model = load_model(path, spaces_from=env)
    if env is not None:
        check_spaces(model.observation_space, env.observation_space, path)
        if not allow_env_mismatch:
            check_world(path, env)
    return _with_masks(model, path, env)


def _with_masks(model: Any, path: str, env: gym.Env | None) -> Any:
    """A MaskablePPO model acting with the wall masks it was trained with (of the env's world, else the file's)."""
    from sb3_contrib import MaskablePPO

    if not isinstance(model, MaskablePPO):
        return model
    from sb3_crowdnav.apg_value.action_masks import WallMaskedPolicy
    from sb3_crowdnav.serialization import read_world, world_of

    world = world_of(env) if env is not None else read_world(path)
    if world is None:
        raise ValueError(f"{path} is a MaskablePPO model: its wall masks need the env it acts in")
    return WallMaskedPolicy(model, world)


def check_world(model_or_path: Any, env: gym.Env) -> None:
    """``ValueError`` when a model was trained in another world than ``env`` (:func:`~sb3_crowdnav.models.world_mismatch`)."""
    from sb3_crowdnav.models import world_mismatch

    mismatch = world_mismatch(model_or_path, env)
    if mismatch:
        raise ValueError(f"{mismatch}; evaluate it in the world it was trained for, or pass allow_env_mismatch=True "
                         "(--allow-env-mismatch) to do so on purpose")


def check_spaces(model_space: Any, env_space: Any, name: str = "the model") -> None:
    """``ValueError`` when a model's observation shapes differ from the env's (e.g. another ``max_humans``).

    The one comparison of a saved model's observation space with an env's, used by the runner and the CLI
    (which reads the model's space from the file without unpickling). A space that is not a ``Dict``
    has no per-key shapes to compare and passes: the model's own loader refuses it.
    """
    want = {k: sp.shape for k, sp in getattr(model_space, "spaces", {}).items()}
    got = {k: sp.shape for k, sp in getattr(env_space, "spaces", {}).items()}
    if want and got and got != want:
        raise ValueError(f"{name} was trained on observations {want} but the env gives {got}; "
                         "use the env, max_humans and history_length it was trained with")


def make_env(env_id: str = DEFAULT_ENV_ID, env_kwargs: Mapping[str, Any] | None = None, **extra: Any) -> gym.Env:
    """``gym.make(env_id, **env_kwargs, **extra)``."""
    return gym.make(env_id, **dict(env_kwargs or {}), **extra)


def _trajectory(env: gym.Env) -> Trajectory:
    base = env.unwrapped
    robot = np.stack([r for r, _ in base.trajectory])
    humans = np.stack([h for _, h in base.trajectory])
    layout = getattr(base, "layout", None)
    return Trajectory(robot=robot, humans=humans, human_goals=np.array(base.sim.human_goals, dtype=float),
                      scene=base.scene, obstacles=tuple(layout.polygons) if layout is not None else ())


def run_episode(env: gym.Env, policy: Any, seed: int, deterministic: bool = True,
                keep_trajectory: bool = False) -> EpisodeRecord:
    """Play one episode of ``env`` from ``reset(seed=seed)`` and return its record."""
    obs, _ = env.reset(seed=int(seed))
    if hasattr(policy, "seed_episode"):
        policy.seed_episode(int(seed))
    elif not deterministic and hasattr(policy, "set_random_seed"):  # an SB3 model sampling its actions
        policy.set_random_seed(int(seed))  # torch, numpy, its action space (and APGValue's ε draws)
    state, episode_start = None, np.ones((1,), dtype=bool)
    total, steps = 0.0, 0
    while True:
        action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        episode_start = np.zeros((1,), dtype=bool)
        obs, reward, terminated, truncated, info = env.step(int(np.asarray(action).reshape(-1)[0]))
        total += float(reward)
        steps += 1
        if terminated or truncated:
            break
    return EpisodeRecord.from_stats(seed, steps, total, info["episode_stats"],
                                    trajectory=_trajectory(env) if keep_trajectory else None)


# ---------------------------------------------------------------- worker processes
_WORKER: dict[str, Any] = {}


def _set_torch_threads(n: int | None) -> None:
    if n is not None and "torch" in sys.modules:  # never import torch just for this (ORCA/random need none)
        sys.modules["torch"].set_num_threads(n)


def _init_worker(spec: PolicySpec, env_id: str, env_kwargs: dict[str, Any], torch_threads: int | None,
                 protective_field: Any = None, lookahead: Mapping[str, Any] | None = None) -> None:
    _set_torch_threads(torch_threads)
    env = make_env(env_id, env_kwargs)
    _WORKER["env"] = env
    _WORKER["policy"] = make_policy(spec, env, allow_env_mismatch=True,  # the parent checked it
                                    protective_field=protective_field, lookahead=lookahead)
    _set_torch_threads(torch_threads)


def _worker_episode(task: tuple[int, bool, bool]) -> EpisodeRecord:
    seed, deterministic, keep = task
    return run_episode(_WORKER["env"], _WORKER["policy"], seed, deterministic, keep)


def eval_seeds(n_episodes: int, seed_offset: int = TEST_SEED_OFFSET) -> list[int]:
    """The seeds of ``n_episodes`` test episodes: ``seed_offset, seed_offset + 1, ...``."""
    return [seed_offset + i for i in range(n_episodes)]


def run_episodes(
    policy: Any,
    n_episodes: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    *,
    env_id: str = DEFAULT_ENV_ID,
    seeds: Iterable[int] | None = None,
    seed_offset: int = TEST_SEED_OFFSET,
    workers: int = 1,
    deterministic: bool = True,
    keep_trajectories: bool = False,
    progress: bool = False,
    desc: str | None = None,
    torch_threads: int | None = 1,
    allow_env_mismatch: bool = False,
    protective_field: Any = None,
    lookahead: Mapping[str, Any] | None = None,
    played: Mapping[int, EpisodeRecord] | None = None,
    on_record: Callable[[EpisodeRecord], None] | None = None,
) -> list[EpisodeRecord]:
    """Evaluate ``policy`` on test episodes and return one :class:`EpisodeRecord` per episode, in seed order.

    :param policy: an object with ``predict`` (only with ``workers=1``) or a spec (:class:`PolicySpec`:
        ``"orca"``, ``"random:SEED"``, ``"pretrained:NAME"``, a model ``.zip`` path, ...)
    :param n_episodes: number of episodes, seeds ``seed_offset + i`` (see :data:`TEST_SEED_OFFSET`)
    :param env_kwargs: keyword arguments of the env (``num_humans``, ``reward``, ``robot_visible``, ...)
    :param seeds: explicit seeds instead of ``n_episodes``/``seed_offset``
    :param workers: number of processes (``spawn``); records are the same for any number
    :param keep_trajectories: attach the full :class:`Trajectory` to every record
    :param progress: show a tqdm progress bar
    :param torch_threads: torch threads in each worker (``None``: leave as is)
    :param allow_env_mismatch: evaluate a model in another world than it was trained for (see :func:`make_policy`)
    :param protective_field: a :class:`~sb3_crowdnav.safety.ProtectiveField` around the policy; None: none
    :param lookahead: a value model's lookahead settings (:func:`with_lookahead`); None: the model's own
    :param played: records of some of the seeds, played before (a resumed run,
        :class:`~sb3_crowdnav.evaluation.journal.EpisodeJournal`): those seeds are not played again, and their
        records are returned as given (without a trajectory when they have none, whatever ``keep_trajectories``)
    :param on_record: called with each record as its episode finishes (not with the ``played`` ones)
    """
    if seeds is None:
        if n_episodes is None:
            raise TypeError("n_episodes must be an int >= 1 when no seeds are given, got None")
        check_int("n_episodes", n_episodes, 1)
        seeds = eval_seeds(int(n_episodes), seed_offset)
    seeds = [int(s) for s in seeds]
    check_int("workers", workers, 1)
    if is_spec(policy):  # a bad spec fails here, before an env is made or a worker started
        policy = PolicySpec.parse(policy)
    env_kwargs = dict(env_kwargs or {})
    done = {s: played[s] for s in seeds if s in played} if played else {}
    todo = [s for s in seeds if s not in done]
    bar = _progress(len(seeds), progress, desc or policy_label(policy))
    bar.update(len(done))

    def finished(record: EpisodeRecord) -> None:
        done[record.seed] = record
        if on_record is not None:
            on_record(record)
        bar.update(1)

    try:
        _play(policy, todo, finished, env_id, env_kwargs, workers, deterministic, keep_trajectories, torch_threads,
              allow_env_mismatch, protective_field, lookahead)
        return [done[s] for s in seeds]
    finally:
        bar.close()


def _play(policy: Any, seeds: list[int], finished: Callable[[EpisodeRecord], None], env_id: str,
          env_kwargs: dict[str, Any], workers: int, deterministic: bool, keep_trajectories: bool,
          torch_threads: int | None, allow_env_mismatch: bool, protective_field: Any,
          lookahead: Mapping[str, Any] | None) -> None:
    """Play the episodes of ``seeds`` (in this process, or in ``workers`` processes), ``finished`` called with each
    record in seed order; the policy is made (and a bad one refused) even when there is nothing left to play."""
    workers = max(1, min(workers, len(seeds)))
    if workers == 1:
        env = make_env(env_id, env_kwargs)
        try:
            pol = make_policy(policy, env, allow_env_mismatch, protective_field, lookahead)
            for s in seeds:
                finished(run_episode(env, pol, s, deterministic, keep_trajectories))
        finally:
            env.close()
        return
    if not isinstance(policy, PolicySpec):
        raise ValueError("workers > 1 needs a picklable policy spec ('orca', 'random', or a model .zip path), "
                         f"not a {type(policy).__name__} object")
    # fail here, not in the workers: a Pool restarts workers whose initializer raises, forever
    env = make_env(env_id, env_kwargs)
    try:
        make_policy(policy, env, allow_env_mismatch, protective_field, lookahead)
    finally:
        env.close()
    ctx = mp.get_context("spawn")
    tasks = [(s, deterministic, keep_trajectories) for s in seeds]
    chunk = max(1, min(16, len(seeds) // (workers * 8)))
    initargs = (policy, env_id, env_kwargs, torch_threads, protective_field, lookahead)
    with ctx.Pool(workers, initializer=_init_worker, initargs=initargs) as pool:
        for record in pool.imap(_worker_episode, tasks, chunksize=chunk):
            finished(record)


def run_sweep(policy: Any, humans: Sequence[int], n_episodes: int, env_kwargs: Mapping[str, Any] | None = None,
              **kwargs: Any) -> dict[int, list[EpisodeRecord]]:
    """Evaluate one policy for each number of pedestrians in ``humans`` (the paper's Table 4).

    ``max_humans`` is raised to the largest N when needed (a trained model must have been built
    with at least that capacity: its observation space is fixed).
    """
    humans = list(humans)
    if not humans:
        raise ValueError(f"humans must be a non-empty list of ints >= 0, got {humans!r}")
    for i, n in enumerate(humans):
        check_int(f"humans[{i}]", n, 0)
    humans = [int(n) for n in humans]
    base = dict(env_kwargs or {})
    base["max_humans"] = max(int(base.get("max_humans", SceneConfig.max_humans)), max(humans))
    out = {}
    for n in humans:
        desc = f"{policy_label(policy)} N={n}"
        out[n] = run_episodes(policy, n_episodes, {**base, "num_humans": n}, desc=desc, **kwargs)
    return out


def records_to_rows(records: Iterable[EpisodeRecord]) -> list[dict[str, Any]]:
    """Scalar fields of each record (for CSV)."""
    return [r.to_dict() for r in records]


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _progress(total: int, enabled: bool, desc: str):
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="ep", dynamic_ncols=True)


__all__ = [
    "DEFAULT_ENV_ID",
    "LOOKAHEAD_KEYS",
    "RECORD_FIELDS",
    "TEST_SEED_OFFSET",
    "EpisodeRecord",
    "RandomPolicy",
    "Trajectory",
    "eval_seeds",
    "make_env",
    "make_policy",
    "policy_label",
    "records_to_rows",
    "run_episode",
    "run_episodes",
    "run_sweep",
    "with_lookahead",
]
