"""Saved models: the algorithms, loading a ``.zip`` without being told its algorithm, the shipped models.

Shipped models: each file in ``sb3_crowdnav/weights/`` is an SB3 ``.zip`` saved without its replay
buffer (policy weights and optimiser state, about 1 MB), loaded by ``pretrained("apg_rl")``. They are
produced by ``sb3-crowdnav train --variant NAME`` (see the docs, "Shipped models and results", for the command, wall time and
results of each).

Loading without being told the algorithm:

:func:`load_model` reads the ``data`` JSON inside the SB3 ``.zip`` and picks the algorithm from
the module of the saved ``policy_class`` (``sb3_crowdnav.apg_value...`` → APGValue,
``stable_baselines3.dqn...`` → DQN), from the class itself for sb3-contrib's QRDQN, RecurrentPPO and MaskablePPO
(a subclass of their policies, decoded without unpickling), or, for policies shared between algorithms (e.g.
``MultiInputPolicy`` of PPO/A2C or our ``ApgDQNPolicy``/``ApgActorCriticPolicy`` in
``sb3_crowdnav.nn``), from hyperparameters only one algorithm saves (``clip_range`` → PPO,
``target_update_interval`` → DQN, ...). When that fails it tries APGValue, DQN, PPO and A2C in turn.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

# name -> algorithm of the file weights/<name>.zip
PRETRAINED = {
    "apg_rl": "apg_value",
    "apg_crl": "apg_value",
    "apg_carl": "apg_value",
    "cadrl": "apg_value",
    "sf_rl": "apg_value",
    "lm_rl": "apg_value",
    "ppo_apg": "ppo",
    "dqn_apg": "dqn",
    "apg_warehouse_paper": "apg_value",
    "ppo_warehouse": "ppo",
    "apg_robust": "apg_value",
    "apg_warehouse": "apg_value",
}
# name -> the env a shipped model was trained for: its id and the keyword arguments that differ from its defaults
# (None: none; the warehouse models of the paper's world: sim.warehouse.config.PAPER_WAREHOUSE; else a dict of them)
PAPER_WORLD = "paper_warehouse"
PRETRAINED_ENV = {name: ("CrowdNav-v0", None) for name in PRETRAINED}
PRETRAINED_ENV.update({"apg_warehouse_paper": ("CrowdNavWarehouse-v0", PAPER_WORLD),
                       "ppo_warehouse": ("CrowdNavWarehouse-v0", PAPER_WORLD),
                       "apg_warehouse": ("CrowdNavWarehouse-v0", None),
                       "apg_robust": ("CrowdNav-v0", {"actions": "with_stop"})})
# name -> SHA-256 of weights/<name>.zip, checked before every load (examples/ship_model.py prints it)
PRETRAINED_SHA256 = {
    "apg_rl": "d747a15de9b4354ffd41c032889e955333d2153387d60e750719e83d3289ab8a",
    "apg_crl": "ddb7e8887a2fec8eaf80af4b6fe545d8586860d0419f04cec80d92d24b781b61",
    "apg_carl": "3cf8f8fc571012f701acf592a588e91929181924096b1de18899ae55f29a9ac2",
    "cadrl": "d1134885815d7411408b0db0286ff508a97a7681b0144a41d803c3f781fe82e1",
    "sf_rl": "47abefd9a25b01b18a52638d130b66c5228e6516457be5768a88823cd6ec03e6",
    "lm_rl": "bb3b01d8d88c503423562d865c2e807def4f314a635fd2f1ea0866d336ed1cab",
    "ppo_apg": "b94d155294700d0b283f655d846783022276dcf9290edcf6dd5c1b6b96154d2f",
    "dqn_apg": "4002a0bdffcb70e967655d430a72a5d1f45a04918dacf247f0c87c78d7ebf94e",
    "ppo_warehouse": "e71d387a6b327616c7d26df7b92ed14f7166616286530fcc8ed31c5a293df208",
    "apg_warehouse_paper": "e1e2ae06da71b01fe614afe609866df603dda9f5a74e1f10030430387395254c",
    "apg_robust": "8f556413c267faab168307eaca56f647b677774298f3aff28844f0b6e33f2a86",
    "apg_warehouse": "f32d970eca31ea030f9e8ab92eea1e2a065d2b7a9b38e18a94c107ae32ecbdd3",
}


def algorithms() -> dict[str, type]:
    """Algorithm name → class: ``apg_value``, ``dqn``, ``dqfd`` (DQN + demonstrations), ``ppo``, ``a2c``, and
    sb3-contrib's ``qrdqn``, ``recurrentppo`` and ``maskableppo``."""
    from sb3_contrib import QRDQN, MaskablePPO, RecurrentPPO
    from stable_baselines3 import A2C, DQN, PPO

    from sb3_crowdnav.apg_value import APGValue
    from sb3_crowdnav.imitation.dqfd import DQfD

    return {"apg_value": APGValue, "dqn": DQN, "dqfd": DQfD, "ppo": PPO, "a2c": A2C, "qrdqn": QRDQN,
            "recurrentppo": RecurrentPPO, "maskableppo": MaskablePPO}


def _contrib_algorithm(policy_class: Any) -> str | None:
    """The sb3-contrib algorithm of a saved ``policy_class`` entry, from the class itself (decoded without unpickling:
    our ``Apg*Policy`` aliases live in ``sb3_crowdnav.nn``, so the module name alone does not tell)."""
    import base64

    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
    from sb3_contrib.qrdqn.policies import QRDQNPolicy

    import sb3_crowdnav.nn.policies  # noqa: F401  (the decoder only resolves classes already imported)
    from sb3_crowdnav.serialization import UnsafeModelFileError, decode

    if not isinstance(policy_class, dict) or ":serialized:" not in policy_class:
        return None
    try:
        cls = decode(base64.b64decode(policy_class[":serialized:"]))
    except (UnsafeModelFileError, ValueError, TypeError, KeyError, IndexError):
        return None
    bases = {"qrdqn": QRDQNPolicy, "recurrentppo": RecurrentActorCriticPolicy, "maskableppo": MaskableActorCriticPolicy}
    return next((name for name, base in bases.items() if isinstance(cls, type) and issubclass(cls, base)), None)


def resolve_model_path(path: str | Path) -> Path:
    """``path`` or ``path + ".zip"``; ``FileNotFoundError`` when neither exists."""
    p = Path(path)
    if p.is_file():
        return p
    if p.suffix != ".zip" and p.with_name(p.name + ".zip").is_file():
        return p.with_name(p.name + ".zip")
    raise FileNotFoundError(f"no saved model at {str(path)!r}")


def _read_data(path: Path) -> dict[str, Any]:
    try:
        with zipfile.ZipFile(path) as archive:
            return json.loads(archive.read("data").decode("utf-8"))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{str(path)!r} is not a Stable-Baselines3 model archive ({exc})") from exc


def detect_algorithm(path: str | Path) -> str | None:
    """The algorithm name (a key of :func:`algorithms`) of a saved model, or ``None`` if unsure."""
    data = _read_data(resolve_model_path(path))
    policy_class = data.get("policy_class")
    module = policy_class.get("__module__", "") if isinstance(policy_class, dict) else ""
    if "apg_value" in module:  # (not "imitation_episodes" in data: the zoo's PPO, DQN, MaskablePPO... save it too)
        return "apg_value"
    if (contrib := _contrib_algorithm(policy_class)) is not None:  # before PPO's and DQN's keys, which they share
        return contrib
    if module.startswith("stable_baselines3.dqn"):
        return "dqn"
    if module.startswith("stable_baselines3.ppo") or "clip_range" in data:
        return "ppo"
    if "target_update_interval" in data and "exploration_fraction" in data:
        return "dqn"
    if "gae_lambda" in data and "n_steps" in data:
        return "a2c"
    return None


def _load(cls: type, path: Path, env: Any, device: str, trusted: bool, spaces_from: Any = None, **kwargs: Any):
    """``cls.load`` without unpickling (:mod:`sb3_crowdnav.serialization`) unless ``trusted``."""
    if not trusted:
        from sb3_crowdnav.serialization import safe_custom_objects

        objects = safe_custom_objects(path, env if env is not None else spaces_from)
        kwargs["custom_objects"] = {**objects, **(kwargs.get("custom_objects") or {})}
    from sb3_crowdnav.apg_value import APGValue

    if issubclass(cls, APGValue):  # its load would build the same objects again
        kwargs["trusted"] = True
    return cls.load(path, env=env, device=device, **kwargs)


def load_model(path: str | Path, env: Any = None, algo: str | None = None, device: str = "cpu", trusted: bool = False,
               spaces_from: Any = None, **kwargs: Any):
    """Load a saved APGValue / DQN / PPO / A2C / QRDQN / RecurrentPPO / MaskablePPO model, detecting the algorithm
    unless ``algo`` is given.

    Nothing in the file is unpickled (:mod:`sb3_crowdnav.serialization`): a file whose entries need it is refused
    with :class:`~sb3_crowdnav.serialization.UnsafeModelFileError` naming the entry.

    :param path: the ``.zip`` (the suffix may be omitted)
    :param env: passed to ``Algorithm.load`` (``None`` is enough to ``predict`` a model this package saved; a
        plain SB3 file needs the env, whose spaces replace the file's pickled ones after a shape check); a model of
        another world than the env's is refused (:func:`world_mismatch`)
    :param algo: a key of :func:`algorithms` (``"apg_value"``, ``"dqn"``, ``"ppo"``, ``"qrdqn"``, ...) to skip detection
    :param trusted: use SB3's own load, which unpickles; only for files you made yourself
    :param spaces_from: an env (not attached to the model) whose spaces stand in for a plain SB3 file's pickled ones
    """
    p = resolve_model_path(path)
    if env is not None and (mismatch := world_mismatch(p, env)):
        raise ValueError(f"{p}: {mismatch}; load it with an env of the world it was trained in")
    algos = algorithms()
    if algo is not None:
        if algo not in algos:
            raise ValueError(f"algo must be one of {sorted(algos)}, got {algo!r}")
        return _load(algos[algo], p, env, device, trusted, spaces_from, **kwargs)
    name = detect_algorithm(p)
    if name is not None:
        return _load(algos[name], p, env, device, trusted, spaces_from, **kwargs)
    from sb3_crowdnav.serialization import UnsafeModelFileError

    errors = []
    for cls_name, cls in algos.items():
        try:
            return _load(cls, p, env, device, trusted, spaces_from, **kwargs)
        except UnsafeModelFileError:
            raise
        except Exception as exc:  # try the next algorithm; report all failures below
            errors.append(f"{cls_name}: {type(exc).__name__}: {exc}")
    raise ValueError(f"could not load {str(p)!r} with any of {sorted(algos)}: " + "; ".join(errors))


def world_mismatch(model_or_path: Any, env: Any) -> str | None:
    """How the world a model was trained in differs from ``env``'s where the model depends on it; None when it does
    not, or when either world is unknown (a model object of SB3's algorithms, an env that is not a crowd env).

    The comparison is :func:`~sb3_crowdnav.sim.world.compare_worlds`: every policy must share the motion fields (time
    step, kinematics, action table); a lookahead (APGValue) also the waypoint rule it predicts with. The rewards a
    model was trained for only matter to further training, which :class:`~sb3_crowdnav.apg_value.APGValue` checks.
    The message ends with the env keyword arguments that give the model its world (``make the env with
    actions='paper', max_acceleration=None, max_turn_rate=None`` for the shipped warehouse models in today's warehouse).
    """
    from sb3_crowdnav.serialization import read_world, world_of
    from sb3_crowdnav.sim.world import MOTION_FIELDS, PREDICTION_FIELDS, World, compare_worlds, env_keywords

    if isinstance(model_or_path, (str, Path)):
        path = resolve_model_path(model_or_path)
        lookahead = detect_algorithm(path) == "apg_value"  # first: it names a file that is no model archive
        trained = read_world(path)
    else:
        trained = getattr(getattr(model_or_path, "policy", None), "world", None)
        lookahead = True  # only lookahead policies hold a world
    actual = world_of(env)
    if not isinstance(trained, World) or actual is None:
        return None
    fields = PREDICTION_FIELDS if lookahead else MOTION_FIELDS
    mismatch = compare_worlds(trained, actual, fields)
    keywords = env_keywords(trained, actual, fields)
    if mismatch and keywords:
        mismatch += f"; to run it in its world, make the env with {', '.join(f'{k}={v!r}' for k, v in keywords.items())}"
    return mismatch


def available_pretrained() -> list[str]:
    """Names of the shipped models present in this installation."""
    return [name for name in PRETRAINED if (WEIGHTS_DIR / f"{name}.zip").exists()]


def pretrained_path(name: str) -> Path:
    """Path of a shipped model; ``ValueError`` names the available ones."""
    if name not in PRETRAINED:
        raise ValueError(f"unknown pretrained model {name!r}; known: {sorted(PRETRAINED)}")
    path = WEIGHTS_DIR / f"{name}.zip"
    if not path.exists():
        raise ValueError(f"pretrained model {name!r} is not shipped in this version; available: {available_pretrained()}")
    return path


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex): what a shipped model is pinned by, a run's ``best.json`` and a results
    folder's ``meta.json`` record."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def check_pretrained(name: str) -> Path:
    """The path of a shipped model after checking its SHA-256 against the pinned one; ``ValueError`` naming the file."""
    path = pretrained_path(name)
    digest = file_sha256(path)
    if digest != PRETRAINED_SHA256[name]:
        raise ValueError(f"{path} does not match the SHA-256 pinned for {name!r} (has {digest[:16]}..., expected "
                         f"{PRETRAINED_SHA256[name][:16]}...): the file was changed; reinstall sb3_crowdnav")
    return path


def pretrained_env(name: str) -> tuple[str, dict[str, Any]]:
    """The env id and keyword arguments of the world a shipped model was trained for (``env_id, kwargs =
    pretrained_env("apg_warehouse_paper")``, then ``gym.make(env_id, **kwargs)``); ``ValueError`` for an unknown
    name."""
    if name not in PRETRAINED:
        raise ValueError(f"unknown pretrained model {name!r}; known: {sorted(PRETRAINED)}")
    env_id, world = PRETRAINED_ENV[name]
    if world == PAPER_WORLD:
        from sb3_crowdnav.sim.warehouse.config import PAPER_WAREHOUSE

        return env_id, dict(PAPER_WAREHOUSE)
    return env_id, dict(world or {})


def pretrained(name: str, env: Any = None, **kwargs: Any):
    """Load a shipped model (``APGValue``, ``PPO`` or ``DQN``) by name, e.g. ``pretrained("apg_rl")``; its file is
    checked against the SHA-256 pinned in the package first."""
    return load_model(check_pretrained(name), env=env, algo=PRETRAINED[name], **kwargs)


__all__ = [
    "PRETRAINED",
    "PRETRAINED_SHA256",
    "WEIGHTS_DIR",
    "algorithms",
    "available_pretrained",
    "check_pretrained",
    "detect_algorithm",
    "file_sha256",
    "load_model",
    "pretrained",
    "pretrained_env",
    "pretrained_path",
    "resolve_model_path",
    "world_mismatch",
]
