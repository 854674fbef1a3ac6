"""Training from an rl-zoo3-format hyperparameter file (``sb3-crowdnav train --hyperparams FILE``).

The YAML has one top-level key per env id, as rl-zoo3 writes it::

    CrowdNav-v0:
      n_timesteps: !!float 2e5
      policy: MultiInputPolicy
      policy_kwargs: "dict(features_extractor_class=apg, net_arch=[64])"
      env_kwargs: {num_humans: 6}
      n_envs: 1
      learning_rate: lin_1e-3
      batch_size: 100

``n_timesteps``, ``policy``, ``policy_kwargs``, ``env_kwargs`` and ``n_envs`` are read here; every
other key goes to the algorithm's constructor. ``policy: ApgPolicy`` names the APG encoder's policy under
every algorithm (:data:`sb3_crowdnav.nn.APG_POLICIES` for SB3's). ``policy_kwargs`` may be a dict or a Python-literal
string; strings are evaluated by :func:`safe_eval`, which knows only ``dict``, literals, ``nn.<Module>``
and the feature-extractor names of :data:`sb3_crowdnav.nn.EXTRACTORS` (``apg``, ``cadrl``, ... and
their class names). ``lin_<x>`` for ``learning_rate``/``clip_range`` is rl-zoo3's linear schedule,
built with SB3's ``LinearSchedule``. ``maskableppo``'s envs are wrapped in
:class:`~sb3_crowdnav.apg_value.action_masks.WallActionMasker` (its file may name it as ``env_wrapper`` for rl-zoo3).

``n_steps > 1`` of DQN, QR-DQN and DQfD (n-step returns) becomes ``replay_buffer_class=NStepDictReplayBuffer,
replay_buffer_kwargs={"n_steps": n, "gamma": gamma}`` (:func:`algorithm_kwargs`, :mod:`sb3_crowdnav.nn.buffers`),
which SB3 2.9 does not build for this package's Dict observations.

Why not rl-zoo3's own reading (its ``ExperimentManager``): it evaluates ``policy_kwargs`` strings with
``eval`` (a hyperparameter file could run code), and it brings its wrappers, normalisation and frame
stacking, which would corrupt the physical observation the lookahead propagates. rl-zoo3 itself
stays fully usable through ``sb3-crowdnav-zoo`` (:mod:`sb3_crowdnav.training.zoo`).
"""

from __future__ import annotations

import ast
import json
import operator
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sb3_crowdnav.sim.validation import check_int, check_positive

DEFAULT_POLICIES = {"apg_value": "ApgPolicy", "dqn": "MultiInputPolicy", "dqfd": "MultiInputPolicy", "ppo": "MultiInputPolicy",
                    "a2c": "MultiInputPolicy", "qrdqn": "MultiInputPolicy", "recurrentppo": "MultiInputLstmPolicy",
                    "maskableppo": "MultiInputPolicy"}
# the env wrapper an algorithm needs, which train_from_hyperparams applies itself (an rl-zoo3 file names it as
# env_wrapper for rl-zoo3; here that entry is accepted for this algorithm only)
ALGO_WRAPPERS = {"maskableppo": "sb3_crowdnav.apg_value.action_masks.WallActionMasker"}
# the ORCA robot imitated before RL: keys a hyperparameter file may set (or the command line), with their defaults
IMITATION_DEFAULTS = {"imitation_episodes": 0, "imitation_epochs": 10, "imitation_learning_rate": 1e-3}
IMITATION_ALGOS = ("ppo", "a2c", "maskableppo", "dqn", "qrdqn", "dqfd")
ZOO_ONLY_KEYS = ("env_wrapper", "callback", "vec_env_wrapper", "frame_stack")
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}


def policy_kwargs_names() -> dict[str, Any]:
    """Names :func:`safe_eval` accepts in ``policy_kwargs``: ``dict``, ``nn`` and the extractors."""
    import torch.nn as nn

    names: dict[str, Any] = {"dict": dict, "nn": nn}
    try:
        from sb3_crowdnav.nn import EXTRACTORS
    except ImportError:  # the extractors are not built (yet)
        EXTRACTORS = {}
    for key, cls in EXTRACTORS.items():
        names[key] = cls
        names[cls.__name__] = cls
    return names


def _eval_name(node: ast.Name, names: Mapping[str, Any]) -> Any:
    if node.id not in names:
        raise ValueError(f"name {node.id!r} is not allowed; allowed: {sorted(names)}")
    return names[node.id]


def _eval_attribute(node: ast.Attribute, names: Mapping[str, Any]) -> Any:
    if isinstance(node.value, ast.Name) and node.value.id == "nn" and "nn" in names:
        import torch.nn as nn

        value = getattr(nn, node.attr, None)
        if isinstance(value, type) and issubclass(value, nn.Module):
            return value
    raise ValueError(f"attribute {ast.unparse(node)!r} is not allowed (only nn.<Module>)")


def _eval_number_op(node: ast.UnaryOp | ast.BinOp, names: Mapping[str, Any]) -> Any:
    if isinstance(node, ast.UnaryOp):
        if not isinstance(node.op, (ast.USub, ast.UAdd)):
            raise ValueError(f"operator in {ast.unparse(node)!r} is not allowed")
        operands = [_eval_node(node.operand, names)]
    else:
        if type(node.op) not in _BINOPS:
            raise ValueError(f"operator in {ast.unparse(node)!r} is not allowed (only + - * /)")
        operands = [_eval_node(node.left, names), _eval_node(node.right, names)]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in operands):
        raise ValueError(f"arithmetic only applies to numbers: {ast.unparse(node)!r}")
    if isinstance(node, ast.UnaryOp):
        return -operands[0] if isinstance(node.op, ast.USub) else operands[0]
    return _BINOPS[type(node.op)](*operands)


def _eval_call(node: ast.Call, names: Mapping[str, Any]) -> Any:
    if _eval_node(node.func, names) is not dict or node.args or any(k.arg is None for k in node.keywords):
        raise ValueError(f"only dict(key=value, ...) calls are allowed, got {ast.unparse(node)!r}")
    return {k.arg: _eval_node(k.value, names) for k in node.keywords}


def _eval_node(node: ast.AST, names: Mapping[str, Any]) -> Any:
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_eval_node(e, names) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        if any(k is None for k in node.keys):
            raise ValueError("'**' unpacking is not allowed")
        return {_eval_node(k, names): _eval_node(v, names) for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, (ast.UnaryOp, ast.BinOp)):
        return _eval_number_op(node, names)
    if isinstance(node, ast.Name):
        return _eval_name(node, names)
    if isinstance(node, ast.Attribute):
        return _eval_attribute(node, names)
    if isinstance(node, ast.Call):
        return _eval_call(node, names)
    raise ValueError(f"{type(node).__name__} is not allowed ({ast.unparse(node)!r})")


def safe_eval(text: str, names: Mapping[str, Any]) -> Any:
    """Evaluate a Python literal with ``dict(...)`` calls, ``nn.<Module>`` and the given names only.

    No ``eval``: the expression is parsed with :mod:`ast` and only literals, lists, tuples, dicts,
    ``dict(key=value)``, ``+ - * /`` on numbers, the given names and ``nn.<Module>`` are evaluated.
    Anything else raises ``ValueError`` naming the construct.
    """
    if not isinstance(text, str):
        raise TypeError(f"safe_eval needs a string, got {type(text).__name__}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"cannot parse {text!r}: {exc.msg}") from None
    return _eval_node(tree.body, names)


def load_hyperparams(path: str | Path, env_id: str = "CrowdNav-v0") -> dict[str, Any]:
    """The ``env_id`` entry of an rl-zoo3 YAML file (a copy)."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no hyperparameter file {str(path)!r}")
    try:
        with path.open() as f:
            content = yaml.safe_load(f)  # plain YAML only: a !!python tag is an error, never a call
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" (line {where.line + 1})" if where is not None else ""
        raise ValueError(f"{str(path)!r} is not valid YAML{line}: {getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(content, dict) or env_id not in content:
        keys = sorted(content) if isinstance(content, dict) else []
        raise ValueError(f"{str(path)!r} has no top-level key {env_id!r} (keys: {keys})")
    entry = content[env_id]
    if entry is None:
        return {}
    if not isinstance(entry, dict):
        raise ValueError(f"{str(path)!r}: {env_id} must be a mapping of hyperparameters")
    return dict(entry)


def _schedule(value: Any) -> Any:
    if isinstance(value, str) and value.startswith("lin_"):
        from stable_baselines3.common.utils import LinearSchedule

        try:
            start = float(value[4:])
        except ValueError:
            raise ValueError(f"a linear schedule is written lin_<number>, got {value!r}") from None
        return LinearSchedule(start, 0.0, 1.0)
    return value


def _check_keys(algo: str, kwargs: Mapping[str, Any]) -> None:
    """``ValueError`` naming a hyperparameter the algorithm's constructor does not take."""
    import inspect

    from sb3_crowdnav.models import algorithms

    cls = algorithms().get(algo)
    if cls is None:
        return
    accepted = set()
    for klass in cls.__mro__:  # DQfD passes **kwargs on to DQN
        if "__init__" in vars(klass):
            accepted |= set(inspect.signature(klass.__init__).parameters)
    accepted = {name for name in accepted if not name.startswith("_")} - {"self", "args", "kwargs", "policy", "env"}
    unknown = sorted(set(kwargs) - accepted)
    if unknown:
        raise ValueError(f"{unknown} {'is not a hyperparameter' if len(unknown) == 1 else 'are not hyperparameters'} "
                         f"of {cls.__name__}; allowed: {sorted(accepted)}")


def prepare(algo: str, hyperparams: Mapping[str, Any]) -> dict[str, Any]:
    """Split rl-zoo3 hyperparameters into ``policy``, ``policy_kwargs``, ``env_kwargs``, ``n_envs``,
    ``n_timesteps`` and the algorithm's constructor ``kwargs``; ``ValueError`` on what is not supported."""
    hp = dict(hyperparams)
    if algo in ALGO_WRAPPERS and hp.get("env_wrapper") == ALGO_WRAPPERS[algo]:
        del hp["env_wrapper"]  # applied by train_from_hyperparams (env_wrapper_class)
    bad = [k for k in ZOO_ONLY_KEYS if hp.get(k)]
    if bad:
        raise ValueError(f"{bad} are not supported by sb3-crowdnav train; use python -m rl_zoo3.train for them")
    for k in ZOO_ONLY_KEYS:
        hp.pop(k, None)
    if hp.pop("normalize", False):
        raise ValueError("normalize: VecNormalize would corrupt the physical states of the observation; remove it")
    names = policy_kwargs_names()
    policy_kwargs = _mapping("policy_kwargs", hp.pop("policy_kwargs", None), names)
    fe = policy_kwargs.get("features_extractor_class")
    if isinstance(fe, str):  # a YAML mapping may name the extractor as a plain string
        if fe not in names or fe in ("dict", "nn"):
            raise ValueError(f"unknown features_extractor_class {fe!r}")
        policy_kwargs["features_extractor_class"] = names[fe]
    env_kwargs = _mapping("env_kwargs", hp.pop("env_kwargs", None), {"dict": dict})
    n_envs = hp.pop("n_envs", 1)
    check_int("n_envs", n_envs, 1)
    n_timesteps = hp.pop("n_timesteps", None)
    policy = hp.pop("policy", DEFAULT_POLICIES.get(algo, "MultiInputPolicy"))
    if policy == "ApgPolicy":  # SB3's algorithms do not know the name (APGValue does): give them the class
        from sb3_crowdnav.nn.policies import APG_POLICIES

        policy = APG_POLICIES.get(algo, policy)
    for key in SCHEDULE_KEYS:
        if key in hp:
            hp[key] = _schedule(hp[key])
    if isinstance(hp.get("train_freq"), list):
        hp["train_freq"] = tuple(hp["train_freq"])
    # the ORCA robot imitated first (APGValue's imitation_* are its own constructor's; others' are refused below)
    imitation = {key: hp.pop(key) for key in IMITATION_DEFAULTS if key in hp} if algo in IMITATION_ALGOS else {}
    _check_keys(algo, hp)
    try:
        n_timesteps = None if n_timesteps is None else int(float(n_timesteps))
    except (TypeError, ValueError):
        raise ValueError(f"n_timesteps must be a number, got {n_timesteps!r}") from None
    return {"policy": policy, "policy_kwargs": policy_kwargs, "env_kwargs": env_kwargs, "n_envs": n_envs,
            "n_timesteps": n_timesteps, "kwargs": hp, "imitation": imitation}


def check_imitation(imitation_episodes: int, imitation_epochs: int, imitation_learning_rate: float) -> None:
    """``ValueError`` naming an imitation setting out of its range (episodes >= 0, epochs >= 1, a rate > 0)."""
    check_int("imitation_episodes", imitation_episodes, 0)
    check_int("imitation_epochs", imitation_epochs, 1)
    check_positive("imitation_learning_rate", imitation_learning_rate)


def imitation_settings(algo: str, cfg: Mapping[str, Any], imitation_episodes: int | None = None,
                       imitation_epochs: int | None = None, imitation_learning_rate: float | None = None) -> dict[str, Any]:
    """The imitation of a run: each setting as given (None: not given), else the file's (``cfg["imitation"]``), else
    :data:`IMITATION_DEFAULTS`'. ``ValueError`` naming the setting when the file and the caller disagree, when a value
    is out of range, or when ``algo`` takes no imitation (ppo, a2c, maskableppo, dqn, qrdqn and dqfd do; dqfd needs
    it)."""
    given = {"imitation_episodes": imitation_episodes, "imitation_epochs": imitation_epochs,
             "imitation_learning_rate": imitation_learning_rate}
    settings = {}
    for key, mine in given.items():
        files = cfg["imitation"].get(key)
        if mine is not None and files is not None and mine != files:
            raise ValueError(f"{key} is {files!r} in the hyperparameter file and {mine!r} here: give it once")
        settings[key] = mine if mine is not None else files if files is not None else IMITATION_DEFAULTS[key]
    check_imitation(**settings)
    if settings["imitation_episodes"] and algo not in IMITATION_ALGOS:
        own = "sets imitation_episodes in its hyperparameter file" if algo == "apg_value" else "takes no imitation"
        raise ValueError(f"imitation_episodes is for {', '.join(IMITATION_ALGOS)}; {algo} {own}")
    if algo == "dqfd" and not settings["imitation_episodes"]:
        raise ValueError("algo 'dqfd' learns from demonstrations: give imitation_episodes >= 1")
    return settings


def _mapping(name: str, value: Any, names: Mapping[str, Any]) -> dict[str, Any]:
    """A YAML mapping, or a Python-literal string of one read by :func:`safe_eval`; ``ValueError`` naming ``name``."""
    if isinstance(value, str):
        try:
            value = safe_eval(value, names)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
    value = value or {}
    if not isinstance(value, dict):
        raise ValueError(f"{name} must be a dict, got {value!r}")
    return value


def algorithm_kwargs(algo: str, cfg: Mapping[str, Any], env: Any) -> dict[str, Any]:
    """The constructor keywords of ``algo`` for ``env`` from :func:`prepare`'s ``cfg``: the file's arguments and
    ``policy_kwargs``, with ``n_steps > 1`` on Dict observations given as an n-step replay buffer
    (:func:`~sb3_crowdnav.nn.buffers.dict_n_step_kwargs`: SB3 2.9 would refuse it)."""
    from sb3_crowdnav.models import algorithms
    from sb3_crowdnav.nn.buffers import dict_n_step_kwargs

    kwargs = dict(cfg["kwargs"])
    if cfg["policy_kwargs"]:
        kwargs["policy_kwargs"] = cfg["policy_kwargs"]
    return dict_n_step_kwargs(algorithms()[algo], env.observation_space, kwargs)


def env_wrapper_class(algo: str) -> type | None:
    """The wrapper every env of ``algo`` gets (:data:`ALGO_WRAPPERS`: MaskablePPO's wall masks), or None."""
    if algo not in ALGO_WRAPPERS:
        return None
    from sb3_crowdnav.apg_value.action_masks import WallActionMasker

    return WallActionMasker


def train_from_hyperparams(algo: str, hyperparams: Mapping[str, Any], out_dir: str | Path, env_id: str = "CrowdNav-v0",
          timesteps: int | None = None, seed: int = 0, progress_bar: bool = False, verbose: int = 0,
          env_overrides: Mapping[str, Any] | None = None, imitation_episodes: int | None = None,
          imitation_epochs: int | None = None, imitation_learning_rate: float | None = None, checkpoint_freq: int = 0,
          wall_time: float | None = None, eval_episodes: int = 0):
    """Train ``algo`` with rl-zoo3 hyperparameters; save ``out_dir/<algo>.zip`` and TensorBoard logs in ``out_dir/tb``.

    Training envs are seeded ``seed, seed + 1, ...`` (``make_vec_env``), far from the test seeds
    (:data:`~sb3_crowdnav.evaluation.runner.TEST_SEED_OFFSET`). Returns ``(model, model_path)``.

    With ``imitation_episodes`` > 0 (PPO, A2C, DQN), the model first imitates that many episodes of
    the ORCA robot (:mod:`sb3_crowdnav.imitation`); APGValue has its own ``imitation_episodes``
    hyperparameter instead. The imitation settings may also be keys of the file (None: :func:`imitation_settings`).

    ``checkpoint_freq`` > 0 saves a checkpoint in ``out_dir/checkpoints/`` every that many env steps (over all envs) and
    after the imitation, with the replay buffer of an off-policy algorithm as plain arrays; the same call again resumes
    the run from the newest one, and returns a finished run as it is (:mod:`sb3_crowdnav.training.zoo_run`; another run
    in the folder is refused). ``wall_time`` [s] stops training at the first env step after that much wall time in all
    (imitation and every resumed segment included; :class:`~sb3_crowdnav.training.callbacks.WallTimeBudget`), whatever
    the timesteps reached: the model's ``num_timesteps`` says how many, ``out_dir/progress.json`` the wall time used.
    With ``checkpoint_freq``, SIGTERM or SIGINT during training writes a checkpoint of the current step and raises
    :class:`~sb3_crowdnav.training.zoo_run.TrainingInterrupted` (the same call again resumes).
    ``eval_episodes`` > 0 (with ``checkpoint_freq``) validates every checkpoint and the final model on that many
    validation episodes and keeps the best as ``out_dir/best.zip`` (:class:`~sb3_crowdnav.training.zoo_run.Validation`).
    """
    start = time.perf_counter()
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    from sb3_crowdnav.models import algorithms, load_model
    from sb3_crowdnav.training import zoo_run
    from sb3_crowdnav.training.run_folder import RunClock, RunLock, atomic_write

    algos = algorithms()
    if algo not in algos:
        raise ValueError(f"algo must be one of {sorted(algos)}, got {algo!r}")
    cfg = prepare(algo, hyperparams)
    n_timesteps = timesteps if timesteps is not None else cfg["n_timesteps"]
    if n_timesteps is None or n_timesteps < 1:
        raise ValueError("the number of timesteps is missing: give --timesteps or n_timesteps in the YAML")
    env_kwargs = {**cfg["env_kwargs"], **dict(env_overrides or {})}
    imitation = imitation_settings(algo, cfg, imitation_episodes=imitation_episodes, imitation_epochs=imitation_epochs,
                                   imitation_learning_rate=imitation_learning_rate)
    imitation_episodes, imitation_epochs, imitation_learning_rate = imitation.values()  # (IMITATION_DEFAULTS' order)
    _check_arguments(checkpoint_freq, wall_time, eval_episodes)
    identity = json.loads(json.dumps({
        "algo": algo, "env_id": env_id, "seed": seed, "hyperparams": dict(hyperparams), "env_kwargs": env_kwargs,
        "timesteps": int(n_timesteps), "wall_time_s": wall_time, **imitation,
        **({"eval_episodes": eval_episodes} if eval_episodes else {})}, default=str))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model_path = out / f"{algo}.zip"
    with RunLock(out):
        progress = zoo_run.read_progress(out, identity)  # another run in this folder is refused before any work
        env = make_vec_env(env_id, n_envs=cfg["n_envs"], seed=seed, env_kwargs=env_kwargs,
                           wrapper_class=env_wrapper_class(algo))
        try:  # the envs are closed however the run ends (finished before, stopped, or failed)
            if progress.get("finished") and model_path.is_file():  # nothing left to do
                return load_model(model_path, env=env, algo=algo), model_path
            kwargs = algorithm_kwargs(algo, cfg, env)
            off_policy = issubclass(algos[algo], OffPolicyAlgorithm)
            resumed = zoo_run.latest_checkpoint(out, algo, off_policy) if progress else None
            clock = RunClock(progress.get("wall_time_s", 0.0) if resumed is not None else 0.0, start)
            validation = zoo_run.Validation(out, algo, eval_episodes, env_id, env_kwargs) if eval_episodes else None
            if resumed is None:
                model = algos[algo](cfg["policy"], env, seed=seed, tensorboard_log=str(out / "tb"), verbose=verbose, **kwargs)
                if imitation_episodes:
                    imitate(model, env, algo, imitation_episodes, imitation_epochs, imitation_learning_rate, verbose)
                if checkpoint_freq:  # the imitation's end: a resumed run does not imitate again
                    zoo_run.save_checkpoint(model, out, algo, clock, identity, validation)
            else:
                model = zoo_run.resume_model(out, algo, resumed, env, seed, verbose, imitation_episodes)
                if validation is not None:  # a kill between the checkpoint and its validation: validated now
                    validation(resumed, zoo_run.checkpoint_file(out, algo, resumed))
                if verbose:
                    print(f"resuming from {zoo_run.checkpoint_file(out, algo, resumed)} ({clock.used:.0f} s used)")
            callbacks: list[Any] = []
            checkpoints = zoo_run.ZooCheckpoint(out, algo, checkpoint_freq, clock, identity, validation) \
                if checkpoint_freq else None
            if checkpoints is not None:
                callbacks.append(checkpoints)
            left = None if wall_time is None else wall_time - clock.used
            if left is not None:
                from sb3_crowdnav.training.callbacks import WallTimeBudget

                callbacks.append(WallTimeBudget(max(left, 1e-9), start))
            if int(n_timesteps) > model.num_timesteps and (left is None or left > 0):
                model.learn(total_timesteps=int(n_timesteps) - (model.num_timesteps if resumed is not None else 0),
                            progress_bar=progress_bar, callback=callbacks or None, reset_num_timesteps=resumed is None)
            if checkpoints is not None and checkpoints.stopped_by is not None:  # validated when the run resumes
                zoo_run.save_checkpoint(model, out, algo, clock, identity)
                steps = int(model.num_timesteps)
                raise zoo_run.TrainingInterrupted(checkpoints.stopped_by, steps, zoo_run.checkpoint_file(out, algo, steps))
            atomic_write(model_path, lambda tmp: zoo_run.save_model(model, tmp))
            if validation is not None:
                validation(int(model.num_timesteps), model_path)
            zoo_run.finish(out, model, clock, identity)
        finally:
            env.close()
    return model, model_path


def _check_arguments(checkpoint_freq: int, wall_time: float | None, eval_episodes: int) -> None:
    check_int("checkpoint_freq", checkpoint_freq, 0)
    check_int("eval_episodes", eval_episodes, 0)
    if eval_episodes and not checkpoint_freq:
        raise ValueError("eval_episodes validates the checkpoints: give checkpoint_freq > 0 too")
    if wall_time is not None:
        check_positive("wall_time", wall_time, " [s]")


def imitate(model: Any, env: Any, algo: str, episodes: int, epochs: int, learning_rate: float, verbose: int) -> None:
    """The ORCA robot's ``episodes`` in ``env`` (a VecEnv) imitated by ``model`` before its RL (``algo``: ``"ppo"``,
    ``"a2c"`` and ``"maskableppo"`` by behaviour cloning, ``"dqn"`` and ``"qrdqn"`` by DQfD's loss with the
    demonstrations left in the replay buffer, ``"dqfd"`` by the same loss with them kept beside it)."""
    from sb3_crowdnav import imitation

    demos = imitation.collect_demonstrations(env, episodes)
    if algo == "dqfd":  # the demonstrations stay beside the replay buffer, not in it
        losses = imitation.pretrain_dqn(model, demos, epochs=epochs, learning_rate=learning_rate,
                                        margin=model.margin, margin_coef=model.margin_coef, fill_buffer=False)
        model.set_demonstrations(demos)
    else:
        pretrain = imitation.pretrain_dqn if algo in ("dqn", "qrdqn") else imitation.pretrain_actor_critic
        losses = pretrain(model, demos, epochs=epochs, learning_rate=learning_rate)
    if verbose:
        print(f"imitation: {len(demos)} transitions of {episodes} ORCA episodes {demos.outcomes}; "
              f"loss per epoch {[round(x, 4) for x in losses]}")
    env.reset()


__all__ = ["ALGO_WRAPPERS", "DEFAULT_POLICIES", "IMITATION_DEFAULTS", "algorithm_kwargs", "check_imitation",
           "env_wrapper_class", "imitate", "imitation_settings", "load_hyperparams", "policy_kwargs_names", "prepare",
           "safe_eval", "train_from_hyperparams"]
