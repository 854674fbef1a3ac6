"""What ``sb3-crowdnav-zoo`` lets rl-zoo3 read: files and command-line dicts parsed, never executed; models loaded
without unpickling.

rl-zoo3 (2.9) runs code from its inputs in several places. It ``exec``s a ``.py`` config and imports a module config;
it ``eval``s the strings of ``policy_kwargs``, ``replay_buffer_class``, ``replay_buffer_kwargs``, ``normalize`` and
``monitor_kwargs`` in a hyperparameter file, and every value of ``--hyperparams``, ``--env-kwargs`` and the other
``key:value`` options (``StoreDict``); it imports and instantiates whatever name a file gives as ``env_wrapper``,
``vec_env_wrapper`` or ``callback``, with the file's arguments (``subprocess.Popen`` as a callback runs a command);
``enjoy`` reads a run's saved ``config.yml`` and ``args.yml`` with PyYAML's ``UnsafeLoader``; and models load with
SB3's unpickling load. ``sb3-crowdnav-zoo`` (:mod:`sb3_crowdnav.training.zoo`) closes each, before rl-zoo3 sees the
input:

- **Configs are YAML files** (``-conf FILE.yml``), read with ``yaml.safe_load``; a ``.py`` or module config is refused
  (it is code: run it with ``python -m rl_zoo3.train`` if it is yours).
- **Strings are parsed** by :func:`~sb3_crowdnav.training.hyperparams.safe_eval` (literals, ``dict(...)``,
  ``nn.<Module>``, the extractors; anything else is a ``ValueError`` naming it): the file's ``policy_kwargs``,
  ``replay_buffer_kwargs``, ``normalize`` and ``monitor_kwargs`` (:func:`checked_hyperparams`), and the values of the
  ``key:value`` options (:class:`SafeStoreDict`). ``replay_buffer_class`` must name a replay buffer of SB3's or this
  package's buffer modules.
- **Wrappers and callbacks must be what they are named as**: each name of ``env_wrapper`` must resolve to a
  ``gymnasium.Wrapper`` class, of ``vec_env_wrapper`` to a ``VecEnvWrapper`` class, of ``callback`` to a
  ``BaseCallback`` class, before rl-zoo3 instantiates it; anything else is refused. The name's module must belong to
  :data:`TRUSTED_PACKAGES` or be imported already (``--gym-packages`` imports a user's own): a file cannot make the
  zoo import a module.
- **Saved runs are read with a loader that builds plain data only** (:func:`load_yaml`: YAML's safe types and the
  ``OrderedDict`` that rl-zoo3 writes), and then checked as a hyperparameter file is.
- **Models load as** :func:`~sb3_crowdnav.models.load_model` **loads them**: the zoo's algorithms take nothing from a
  file's pickles (:class:`SafeLoadMixin`; ``trusted=True`` for SB3's own load), and their ``save`` writes the plain
  spaces member that lets a model load without its env. Their replay buffers are saved as plain arrays and a pickled
  one is refused (rl-zoo3 reloads ``replay_buffer.pkl`` beside a ``--trained-agent``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import types
from collections import OrderedDict
from pathlib import Path
from typing import Any

import yaml

PARSED_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "normalize", "monitor_kwargs")
CLASS_KEYS = {"env_wrapper": ("gymnasium", "Wrapper"), "vec_env_wrapper": ("stable_baselines3.common.vec_env",
                                                                           "VecEnvWrapper"),
              "callback": ("stable_baselines3.common.callbacks", "BaseCallback")}
BUFFER_MODULES = ("stable_baselines3.common.buffers", "sb3_crowdnav.nn.buffers")
# the packages whose modules a file may name (importing one runs its code): this package and its dependencies
TRUSTED_PACKAGES = ("sb3_crowdnav", "stable_baselines3", "sb3_contrib", "rl_zoo3", "gymnasium")


class RefusedInput(ValueError):
    """An input that rl-zoo3 would execute or instantiate and ``sb3-crowdnav-zoo`` refuses (the message names it)."""


def check_config(path: str) -> None:
    """Refuse a config that is not a YAML file (rl-zoo3 executes a ``.py`` config and imports a module one)."""
    if not str(path).endswith((".yml", ".yaml")):
        raise RefusedInput(f"-conf {path!r}: sb3-crowdnav-zoo reads YAML hyperparameter files only (.yml, .yaml); a .py "
                         "or module config is code, which it does not run (python -m rl_zoo3.train runs your own)")


def _class_named(key: str, name: Any) -> None:
    """Check that ``name`` (a dotted ``module.Class`` string) is a class of ``key``'s kind."""
    module_name, base_name = CLASS_KEYS[key]
    base = getattr(importlib.import_module(module_name), base_name)
    if not isinstance(name, str) or "." not in name:
        raise RefusedInput(f"{key}: {name!r} must be a dotted name 'module.Class' of a {base_name} subclass")
    module, _, attribute = name.rpartition(".")
    if module not in sys.modules and module.split(".")[0] not in TRUSTED_PACKAGES:  # importing runs the module's code
        raise RefusedInput(f"{key}: {name!r} is in a module that is not imported; a class of "
                           f"{', '.join(TRUSTED_PACKAGES)} or of a package imported first (--gym-packages PACKAGE)")
    try:
        found = getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as exc:
        raise RefusedInput(f"{key}: cannot find {name!r} ({exc})") from None
    if not (isinstance(found, type) and issubclass(found, base)):
        raise RefusedInput(f"{key}: {name!r} is not a {base_name} subclass; sb3-crowdnav-zoo only instantiates "
                         f"{base_name} classes there")


def _buffer_class(name: str) -> type:
    from stable_baselines3.common.buffers import ReplayBuffer

    for module in BUFFER_MODULES:
        found = getattr(importlib.import_module(module), name, None) if name.isidentifier() else None
        if isinstance(found, type) and issubclass(found, ReplayBuffer):
            return found
    raise RefusedInput(f"replay_buffer_class: {name!r} is not a replay buffer of {' or '.join(BUFFER_MODULES)}")


def checked_hyperparams(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` with the strings rl-zoo3 would ``eval`` parsed instead (:data:`PARSED_KEYS` by
    :func:`~sb3_crowdnav.training.hyperparams.safe_eval`, ``replay_buffer_class`` to its class), after checking the
    names of :data:`CLASS_KEYS`; :class:`RefusedInput` (a ``ValueError``) names the first key that is refused. The
    mapping is changed in place (and returned)."""
    from sb3_crowdnav.training.hyperparams import policy_kwargs_names, safe_eval

    for key in PARSED_KEYS:
        value = hyperparams.get(key)
        if isinstance(value, str):
            try:
                hyperparams[key] = safe_eval(value, policy_kwargs_names() if key == "policy_kwargs" else {"dict": dict})
            except ValueError as exc:
                raise RefusedInput(f"{key}: {exc}") from None
    if isinstance(hyperparams.get("replay_buffer_class"), str):
        hyperparams["replay_buffer_class"] = _buffer_class(hyperparams["replay_buffer_class"])
    for key in CLASS_KEYS:
        value = hyperparams.get(key)
        for entry in value if isinstance(value, list) else [] if value is None else [value]:
            if isinstance(entry, dict):  # {name: kwargs}
                if len(entry) != 1:
                    raise RefusedInput(f"{key}: {entry!r} must map one class name to its keyword arguments")
                entry = next(iter(entry))
            _class_named(key, entry)
    return hyperparams


class _RunLoader(yaml.SafeLoader):
    """YAML's safe types and the ``OrderedDict`` rl-zoo3 writes (``!!python/object/apply:collections.OrderedDict``
    of ``[key, value]`` pairs); any other tag is an error."""


def _ordered_dict(loader: _RunLoader, node: yaml.Node) -> OrderedDict:
    """The apply tag's one argument, a list of ``[key, value]`` pairs (its sequence form, or ``{args: [...]}``)."""
    if isinstance(node, yaml.MappingNode):
        args = loader.construct_mapping(node, deep=True).get("args", [])
    else:
        args = loader.construct_sequence(node, deep=True)
    pairs = args[0] if len(args) == 1 else None
    if not isinstance(pairs, list) or not all(isinstance(p, list) and len(p) == 2 for p in pairs):
        raise yaml.constructor.ConstructorError(None, None, "an OrderedDict must be a list of [key, value] pairs",
                                                node.start_mark)
    return OrderedDict((k, v) for k, v in pairs)


_RunLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def load_yaml(stream: Any, Loader: Any = None) -> Any:
    """``yaml.load`` for rl-zoo3's saved runs, whatever ``Loader`` it asks for: :class:`_RunLoader`, then
    :func:`checked_hyperparams` on a mapping."""
    data = yaml.load(stream, Loader=_RunLoader)  # (a SafeLoader subclass)
    return checked_hyperparams(data) if isinstance(data, dict) else data


def safe_yaml_module() -> types.ModuleType:
    """A stand-in for the ``yaml`` module inside rl-zoo3's modules: PyYAML with ``load`` replaced by
    :func:`load_yaml`."""
    module = types.ModuleType("yaml")
    module.__dict__.update({k: v for k, v in vars(yaml).items() if not k.startswith("__")})
    module.load = load_yaml
    return module


class SafeStoreDict(argparse.Action):
    """rl-zoo3's ``StoreDict`` (``key:value`` arguments into a dict), with each value parsed by
    :func:`~sb3_crowdnav.training.hyperparams.safe_eval` instead of ``eval``."""

    def __init__(self, option_strings, dest, nargs=None, **kwargs):
        self._nargs = nargs
        super().__init__(option_strings, dest, nargs=nargs, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from sb3_crowdnav.training.hyperparams import policy_kwargs_names, safe_eval

        parsed = {}
        for argument in values:
            key, *rest = argument.split(":")  # (rl-zoo3's split: the key before the first colon)
            value = ":".join(rest)
            try:
                parsed[key] = safe_eval(value, policy_kwargs_names())
            except (ValueError, TypeError) as exc:
                parser.error(f"{option_string} {argument!r}: {exc}")
        setattr(namespace, self.dest, parsed)


class SafeLoadMixin:
    """``load`` as :func:`~sb3_crowdnav.models.load_model` does it (nothing unpickled; ``trusted=True`` for SB3's own
    load), and ``save`` writing the plain spaces member beside SB3's (so that a model loads without its env)."""

    @classmethod
    def load(cls, path: Any, env: Any = None, device: Any = "auto", custom_objects: dict | None = None,
             trusted: bool = False, **kwargs: Any) -> Any:
        if not trusted:
            from sb3_crowdnav.models import resolve_model_path
            from sb3_crowdnav.serialization import safe_custom_objects

            custom_objects = {**safe_custom_objects(resolve_model_path(path), env), **(custom_objects or {})}
        return super().load(path, env=env, device=device, custom_objects=custom_objects, **kwargs)

    def save_replay_buffer(self, path: Any) -> None:
        """The replay buffer as plain arrays (:func:`~sb3_crowdnav.apg_value.buffers.save_buffer`), whatever the
        file's name (rl-zoo3's ``--save-replay-buffer`` writes ``replay_buffer.pkl``)."""
        from sb3_crowdnav.apg_value.buffers import save_buffer

        save_buffer(self.replay_buffer, path)

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True, trusted: bool = False) -> None:
        """A buffer of plain arrays (what :meth:`save_replay_buffer` writes); a pickled one (SB3's) only with
        ``trusted=True``."""
        if trusted:
            return super().load_replay_buffer(path, truncate_last_traj)
        from sb3_crowdnav.apg_value.buffers import is_npz, load_buffer

        if not is_npz(path):
            raise RefusedInput(f"{path}: a pickled replay buffer is not loaded (unpickling can run code); only a buffer "
                               "of plain arrays, as the zoo's algorithms save it")
        load_buffer(self.replay_buffer, path)
        return None

    def save(self, path: Any, *args: Any, **kwargs: Any) -> None:
        from sb3_crowdnav.serialization import write_spaces

        super().save(path, *args, **kwargs)
        if isinstance(path, (str, Path)):  # (a file object: SB3's own member only)
            written = Path(path) if Path(path).suffix else Path(f"{path}.zip")  # (SB3's rule: ".zip" if no suffix)
            write_spaces(written, self.observation_space, self.action_space, self.get_env())


__all__ = ["RefusedInput", "SafeLoadMixin", "SafeStoreDict", "check_config", "checked_hyperparams", "load_yaml",
           "safe_yaml_module"]
