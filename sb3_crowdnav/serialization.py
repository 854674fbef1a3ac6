"""Reading SB3 model files without unpickling anything they hold.

An SB3 ``.zip`` stores its weights as ``.pth`` members (read by torch with ``weights_only=True``) and the
rest in a JSON member ``data``, where every object JSON cannot hold is a ``cloudpickle`` blob under
``":serialized:"``. Unpickling such a blob can run any code the file's author chose. Every loader of this
package instead passes SB3 a replacement for each blob (SB3's ``custom_objects``), built here from plain
values only:

- class references (``policy_class``, the buffer classes, optimiser and activation classes inside
  ``policy_kwargs``) are *decoded*, not unpickled: :func:`decode` walks the pickle's opcodes and accepts
  literals, containers and references to an allow-list of classes that are already imported
  (SB3 / sb3-contrib / sb3_crowdnav policies, extractors and buffers, torch optimisers and activations), never calling
  anything but SB3's ``TrainFreq`` and its unit; any other opcode or name is refused, naming the entry;
- the observation and action spaces come from a plain JSON member ``sb3_crowdnav.json`` that this
  package writes next to ``data`` when it saves a model (:func:`write_spaces`), or else from the env the
  model is loaded with (after checking the file's plain shape description against it);
- the world the model was trained in (:class:`~sb3_crowdnav.sim.world.World`) is plain JSON: an APGValue
  file's ``policy_kwargs["world"]``, or the ``world`` entry of ``sb3_crowdnav.json`` for SB3's algorithms
  (:func:`read_world`);
- schedules are rebuilt from their plain description (``ConstantSchedule(val=0.1)``) or left to the
  algorithm, which rebuilds ``lr_schedule`` and ``exploration_schedule`` from plain numbers on load;
- episode buffers and the last observation are dropped (SB3 starts new ones).

A file that needs more is refused with :class:`UnsafeModelFileError` naming the entry; ``trusted=True`` on
the loaders restores SB3's own (unpickling) load for files you made yourself.
"""

from __future__ import annotations

import base64
import json
import pickletools
import re
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_crowdnav.sim.world import LEGACY_KEYS, World, upgrade_policy_kwargs

SPACES_MEMBER = "sb3_crowdnav.json"
DROPPED = ("_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer", "ep_success_buffer")
RECOMPUTED = ("lr_schedule", "exploration_schedule")  # rebuilt by the algorithm's _setup_model from plain numbers
SCHEDULES = ("clip_range", "clip_range_vf", "learning_rate")
ALLOWED_PREFIXES = ("sb3_crowdnav.", "stable_baselines3.", "sb3_contrib.", "torch.optim.", "torch.nn.modules.")


class UnsafeModelFileError(ValueError):
    """A model file whose content could only be read by unpickling (running code from the file)."""


# ------------------------------------------------------------------ decoding class references
def _allowed(module: str, name: str) -> Any:
    """The already-imported class ``module.name`` when it is on the allow-list; else ``UnsafeModelFileError``."""
    from stable_baselines3.common.buffers import BaseBuffer
    from stable_baselines3.common.policies import BasePolicy
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit
    from torch import nn, optim

    mod = sys.modules.get(module)
    obj = getattr(mod, name, None) if mod is not None and module.startswith(ALLOWED_PREFIXES) and "." not in name else None
    if obj in (TrainFreq, TrainFrequencyUnit):
        return obj
    bases = (BasePolicy, BaseFeaturesExtractor, BaseBuffer, optim.Optimizer, nn.Module)
    if isinstance(obj, type) and issubclass(obj, bases) and obj.__module__ == module:
        return obj
    raise UnsafeModelFileError(f"{module}.{name} is not a class this package loads from a model file")


_CONSTANTS = {"NONE": None, "NEWTRUE": True, "NEWFALSE": False, "EMPTY_TUPLE": ()}
_VALUES = {"BININT", "BININT1", "BININT2", "LONG1", "BINFLOAT", "SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8",
           "UNICODE", "SHORT_BINBYTES", "BINBYTES", "INT", "FLOAT"}
_SKIPPED = {"PROTO", "FRAME"}


class _Decoder:
    """The stack machine of a pickle, restricted to data and allow-listed class references (see :func:`decode`)."""

    def __init__(self) -> None:
        self.stack: list[Any] = []
        self.marks: list[int] = []
        self.memo: dict[int, Any] = {}

    def run(self, blob: bytes) -> Any:
        for op, arg, _ in pickletools.genops(blob):
            name = op.name
            if name == "STOP":
                return self.stack.pop()
            if name in _SKIPPED:
                continue
            if name in _VALUES:
                self.stack.append(arg)
            elif name in _CONSTANTS:
                self.stack.append(_CONSTANTS[name])
            else:
                handler = getattr(self, f"op_{name}", None)
                if handler is None:
                    raise UnsafeModelFileError(f"the pickled value uses {name}, which only unpickling could read")
                handler(arg)
        raise UnsafeModelFileError("the pickled value has no end")

    def _since_mark(self) -> list[Any]:
        start = self.marks.pop()
        items = self.stack[start:]
        del self.stack[start:]
        return items

    def op_MEMOIZE(self, arg: Any) -> None:
        self.memo[len(self.memo)] = self.stack[-1]

    def op_BINPUT(self, arg: int) -> None:
        self.memo[arg] = self.stack[-1]

    op_LONG_BINPUT = op_BINPUT

    def op_BINGET(self, arg: int) -> None:
        self.stack.append(self.memo[arg])

    op_LONG_BINGET = op_BINGET

    def op_MARK(self, arg: Any) -> None:
        self.marks.append(len(self.stack))

    def op_EMPTY_DICT(self, arg: Any) -> None:
        self.stack.append({})

    def op_EMPTY_LIST(self, arg: Any) -> None:
        self.stack.append([])

    def _tuple(self, n: int) -> None:
        items = tuple(self.stack[len(self.stack) - n:])
        del self.stack[len(self.stack) - n:]
        self.stack.append(items)

    def op_TUPLE1(self, arg: Any) -> None:
        self._tuple(1)

    def op_TUPLE2(self, arg: Any) -> None:
        self._tuple(2)

    def op_TUPLE3(self, arg: Any) -> None:
        self._tuple(3)

    def op_TUPLE(self, arg: Any) -> None:
        self.stack.append(tuple(self._since_mark()))

    def op_LIST(self, arg: Any) -> None:
        self.stack.append(self._since_mark())

    def op_DICT(self, arg: Any) -> None:
        items = self._since_mark()
        self.stack.append(dict(zip(items[::2], items[1::2], strict=True)))

    def op_APPENDS(self, arg: Any) -> None:
        items = self._since_mark()
        self.stack[-1].extend(items)

    def op_SETITEMS(self, arg: Any) -> None:
        items = self._since_mark()
        self.stack[-1].update(zip(items[::2], items[1::2], strict=True))

    def op_APPEND(self, arg: Any) -> None:
        value = self.stack.pop()
        self.stack[-1].append(value)

    def op_SETITEM(self, arg: Any) -> None:
        value, key = self.stack.pop(), self.stack.pop()
        self.stack[-1][key] = value

    def op_STACK_GLOBAL(self, arg: Any) -> None:
        attr, module = self.stack.pop(), self.stack.pop()
        self.stack.append(_allowed(module, attr))

    def op_GLOBAL(self, arg: str) -> None:
        module, attr = arg.split(" ", 1)
        self.stack.append(_allowed(module, attr))

    def op_REDUCE(self, arg: Any) -> None:
        """Only SB3's ``TrainFrequencyUnit(value)`` and ``TrainFreq(frequency, unit)`` are ever called."""
        from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

        args, cls = self.stack.pop(), self.stack.pop()
        if cls not in (TrainFreq, TrainFrequencyUnit) or not isinstance(args, tuple):
            raise UnsafeModelFileError(f"the pickled value calls {getattr(cls, '__name__', cls)!s}, which only "
                                       "unpickling could do")
        self.stack.append(cls(*args))

    op_NEWOBJ = op_REDUCE


def decode(blob: bytes) -> Any:
    """Rebuild a pickled value of literals, lists, tuples, dicts and allow-listed class references.

    No pickle machinery runs: the opcodes are read with :mod:`pickletools` and interpreted here. The only
    calls made are SB3's ``TrainFrequencyUnit(value)`` and ``TrainFreq(frequency, unit)``.
    """
    return _Decoder().run(blob)


# ------------------------------------------------------------------ spaces as plain JSON
def space_to_dict(space: spaces.Space) -> dict[str, Any]:
    """A Box, Discrete or Dict of them as plain JSON values (exact: float32 bounds survive the round trip)."""
    if isinstance(space, spaces.Dict):
        return {"type": "Dict", "spaces": {k: space_to_dict(v) for k, v in space.spaces.items()}}
    if isinstance(space, spaces.Box):
        return {"type": "Box", "low": space.low.tolist(), "high": space.high.tolist(), "shape": list(space.shape),
                "dtype": str(space.dtype)}
    if isinstance(space, spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    raise TypeError(f"cannot describe a {type(space).__name__} as plain JSON")


def space_from_dict(data: dict[str, Any]) -> spaces.Space:
    kind = data.get("type")
    if kind == "Dict":
        return spaces.Dict({k: space_from_dict(v) for k, v in data["spaces"].items()})
    if kind == "Box":
        dtype = np.dtype(data["dtype"])
        if dtype.kind not in "fiu":
            raise UnsafeModelFileError(f"a Box of dtype {dtype} is not supported")
        return spaces.Box(np.asarray(data["low"], dtype=dtype), np.asarray(data["high"], dtype=dtype),
                          tuple(data["shape"]), dtype)
    if kind == "Discrete":
        return spaces.Discrete(int(data["n"]), start=int(data["start"]))
    raise UnsafeModelFileError(f"unknown space type {kind!r}")


def world_of(env: Any) -> World | None:
    """The :class:`~sb3_crowdnav.sim.world.World` a crowd env (or VecEnv of them) publishes; None for another env."""
    try:
        world = env.get_attr("world")[0] if hasattr(env, "get_attr") else env.unwrapped.world
    except AttributeError:
        return None
    return world if isinstance(world, World) else None


def read_world(path: str | Path) -> World | None:
    """The world a saved model was trained in (None when the file does not say).

    An APGValue file holds it in its plain ``policy_kwargs`` (entry ``world``), a file of SB3's algorithms in the
    member ``sb3_crowdnav.json`` (entry ``world``); files saved before the world contract, in either place, are read
    by the one converter (:func:`~sb3_crowdnav.sim.world.upgrade_policy_kwargs`, :meth:`World.from_legacy`).
    """
    with zipfile.ZipFile(path) as archive:
        plain = json.loads(archive.read(SPACES_MEMBER)) if SPACES_MEMBER in archive.namelist() else {}
        data = json.loads(archive.read("data").decode("utf-8"))
    if plain.get("world"):
        world = plain["world"]
        return World.from_legacy(world) if set(world) <= set(LEGACY_KEYS) else World.from_dict(world)
    kwargs = data.get("policy_kwargs")
    if not isinstance(kwargs, dict):
        return None
    world = upgrade_policy_kwargs(kwargs).get("world")
    return None if world is None else World.from_dict(world)


def write_spaces(path: str | Path, observation_space: spaces.Space, action_space: spaces.Space,
                 env: Any = None, world: World | None = None) -> None:
    """Add the plain description of the model's spaces (and of its world: ``world``, or else its crowd ``env``'s) to
    the saved ``.zip`` (member ``sb3_crowdnav.json``).

    The world is for SB3's algorithms, whose policies do not hold one; an APGValue file keeps it in its policy_kwargs.
    """
    content: dict[str, Any] = {"observation_space": space_to_dict(observation_space),
                               "action_space": space_to_dict(action_space)}
    world = world if world is not None else world_of(env) if env is not None else None
    if world is not None:
        content["world"] = world.to_dict()
    text = json.dumps(content)
    with zipfile.ZipFile(path, "a") as archive:
        if SPACES_MEMBER not in archive.namelist():
            archive.writestr(SPACES_MEMBER, text)


# ------------------------------------------------------------------ the replacements
_NUMBER = r"([-+]?[0-9.]+(?:[eE][-+]?[0-9]+)?)"
_CONSTANT = re.compile(rf"ConstantSchedule\(val={_NUMBER}\)")
_LINEAR = re.compile(rf"LinearSchedule\(start={_NUMBER}, end={_NUMBER}, end_fraction={_NUMBER}\)")


def _schedule(key: str, entry: dict[str, Any]) -> Any:
    """A constant (float) or SB3 ``LinearSchedule`` rebuilt from the entry's plain description."""
    from stable_baselines3.common.utils import LinearSchedule

    if {"start", "end", "end_fraction"} <= set(entry):  # a LinearSchedule's own attributes
        return LinearSchedule(float(entry["start"]), float(entry["end"]), float(entry["end_fraction"]))
    if "val" in entry:  # a ConstantSchedule's
        return float(entry["val"])
    text = entry.get("value_schedule", "")  # a FloatSchedule wrapping one of them, described by its repr
    text = text if isinstance(text, str) else ""
    if (match := _CONSTANT.fullmatch(text)) is not None:
        return float(match.group(1))
    if (match := _LINEAR.fullmatch(text)) is not None:
        return LinearSchedule(*(float(g) for g in match.groups()))
    raise UnsafeModelFileError(f"entry {key!r} is a schedule ({text or entry.get(':type:')}) that only "
                               "unpickling could rebuild")


_BOX_SHAPES = re.compile(r"'(\w+)': Box\(.*?\((\d+(?:, *\d+)*),?\), (\w+)\)", re.DOTALL)


def _check_env_spaces(data: dict[str, Any], env: Any, path: Path) -> None:
    """The file's plain description of its spaces must match the env's (the spaces are then taken from the env)."""
    obs, act = env.observation_space, env.action_space
    plain_n = data["action_space"].get("n")
    if isinstance(act, spaces.Discrete) and plain_n is not None and int(plain_n) != int(act.n):
        raise UnsafeModelFileError(f"{path}: the model acts in Discrete({plain_n}), the env in {act}")
    described = data["observation_space"].get("spaces")
    if isinstance(obs, spaces.Dict) and isinstance(described, str):
        shapes = {k: tuple(int(x) for x in dims.replace(" ", "").split(",") if x) for k, dims, _ in
                  _BOX_SHAPES.findall(described)}
        env_shapes = {k: tuple(v.shape) for k, v in obs.spaces.items()}
        if shapes != env_shapes:
            raise UnsafeModelFileError(f"{path}: the model was saved for observations {shapes}, the env has "
                                       f"{env_shapes}; use the same max_humans and history_length as in training")


def same_layout(saved: Any, current: Any) -> bool:
    """Whether two spaces have the same kind, keys, shapes and dtypes, whatever their bounds.

    A model loaded with an env whose observation space differs from the saved one only in its ``Box`` bounds takes
    the env's space: the bounds declare the range an env's observations stay in (wider with a faster crowd, a
    recording's frame), and no network here reads them (the features are robot-centric values). Another layout stays
    the saved space, which the loaders then refuse, naming the shapes.
    """
    if isinstance(saved, spaces.Dict) and isinstance(current, spaces.Dict):
        return saved.spaces.keys() == current.spaces.keys() and all(
            same_layout(saved[k], current[k]) for k in saved.spaces)
    if isinstance(saved, spaces.Box) and isinstance(current, spaces.Box):
        return saved.shape == current.shape and saved.dtype == current.dtype
    return saved == current


def _saved_or_env_space(saved: Any, env: Any, key: str) -> Any:
    """The env's space ``key`` when it has the saved one's layout (:func:`same_layout`), else the saved one."""
    current = getattr(env, key, None) if env is not None else None
    return current if current is not None and same_layout(saved, current) else saved


def _check_value_model(data: dict[str, Any], path: Any) -> None:
    """``TypeError`` saying which loader to use when an APGValue loader is given another algorithm's file."""
    if "imitation_episodes" in data:
        return
    module = data.get("policy_class", {}).get("__module__", "") if isinstance(data.get("policy_class"), dict) else ""
    kind = ("PPO" if "clip_range" in data else "DQN" if "exploration_fraction" in data
            else "A2C" if "gae_lambda" in data else module or "another algorithm")
    raise TypeError(f"{path} holds a {kind} model, not an APGValue one: load it with {kind}.load(...) or, for any "
                    "algorithm, sb3_crowdnav.models.load_model(path)")


def safe_custom_objects(path: Any, env: Any = None, value_model: bool = False) -> dict[str, Any]:
    """SB3 ``custom_objects`` replacing every pickled entry of the model file ``path`` (see the module docstring).

    :param env: the env (or VecEnv) the model will be used with, when known: its spaces replace the file's
        when the file has no ``sb3_crowdnav.json`` member
    :param value_model: the caller is APGValue: another algorithm's file is a ``TypeError`` naming its loader
    :raises UnsafeModelFileError: naming the entry that only unpickling could read
    """
    source: Any = path
    if isinstance(path, (str, Path)):
        path = Path(path)
        if not path.exists() and path.suffix != ".zip" and path.with_name(path.name + ".zip").exists():
            path = path.with_name(path.name + ".zip")  # SB3's convention: the suffix may be omitted
        source = path
    try:
        with zipfile.ZipFile(source) as archive:
            data = json.loads(archive.read("data").decode("utf-8"))
            plain = json.loads(archive.read(SPACES_MEMBER)) if SPACES_MEMBER in archive.namelist() else None
        if hasattr(source, "seek"):  # a file object: SB3 reads it again
            source.seek(0)
        if value_model:
            _check_value_model(data, path)
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{str(path)!r} is not a Stable-Baselines3 model archive ({exc})") from exc
    objects: dict[str, Any] = {}
    for key, entry in data.items():
        if not (isinstance(entry, dict) and ":serialized:" in entry):
            continue
        if key in DROPPED or key in RECOMPUTED:
            objects[key] = None
        elif key in ("observation_space", "action_space"):
            if plain is not None:
                objects[key] = _saved_or_env_space(space_from_dict(plain[key]), env, key)
            elif env is not None:
                _check_env_spaces(data, env, path)
                objects[key] = getattr(env, key)
            else:
                raise UnsafeModelFileError(
                    f"{path}: entry {key!r} can only be read by unpickling (the file has no {SPACES_MEMBER}); "
                    "load it with the env it was trained for (env=...), or with trusted=True if you made it yourself")
        elif key in SCHEDULES:
            objects[key] = _schedule(key, entry)
        else:
            try:
                objects[key] = decode(base64.b64decode(entry[":serialized:"]))
            except UnsafeModelFileError as exc:
                raise UnsafeModelFileError(f"{path}: entry {key!r}: {exc}; load with trusted=True only if you made "
                                           "this file yourself") from None
            except (IndexError, KeyError, TypeError, ValueError) as exc:
                raise UnsafeModelFileError(f"{path}: entry {key!r} is malformed ({exc})") from None
    return objects


__all__ = [
    "SPACES_MEMBER",
    "UnsafeModelFileError",
    "decode",
    "read_world",
    "safe_custom_objects",
    "space_from_dict",
    "space_to_dict",
    "world_of",
    "write_spaces",
]
