"""The checks of a ``--policy`` before any episode runs (``evaluate``, ``benchmark``, ``render``): the spec's grammar,
a shipped model's hash, a file's loadability without unpickling, the model's observation shapes and its world."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import UsageError
from sb3_crowdnav.evaluation.policy_spec import GRAMMAR, PolicySpec


def check_policy(spec: str, env_id: str = "CrowdNav-v0", env_kwargs: dict[str, Any] | None = None,
                  allow_env_mismatch: bool = False) -> PolicySpec:
    """The parsed policy spec, checked before any episode runs: a shipped model's hash, a file's loadability
    without unpickling (with the env's spaces for a plain SB3 file), the model's observation shapes and world."""
    try:
        parsed = PolicySpec.parse(spec, name="--policy")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not parsed.is_model:
        return parsed
    if parsed.is_onnx:
        _check_graph(Path(str(parsed.argument)), env_id, env_kwargs, allow_env_mismatch)
        return parsed
    if parsed.kind == "pretrained":
        from sb3_crowdnav.models import check_pretrained

        try:
            path = check_pretrained(str(parsed.argument))
        except ValueError as exc:
            raise UsageError(f"--policy: {exc}") from None
    else:
        path = _resolve_file(spec, str(parsed.argument))
        parsed = PolicySpec("file", str(path))
    _check_shapes(path, env_id, env_kwargs)
    _check_world(path, env_id, env_kwargs, allow_env_mismatch)
    return parsed


def _resolve_file(spec: str, text: str) -> Path:
    """The saved model a file spec names, its algorithm detected; a file named like a shipped model gets a note."""
    from sb3_crowdnav.models import PRETRAINED, detect_algorithm, resolve_model_path

    stem = Path(text).name.removesuffix(".zip")
    shipped = stem if stem in PRETRAINED else None
    try:
        path = resolve_model_path(text)
        detect_algorithm(path)
    except (FileNotFoundError, ValueError) as exc:
        hint = f"; the shipped model is --policy pretrained:{shipped}" if shipped else ""
        raise UsageError(f"--policy {spec!r}: expected {GRAMMAR} ({exc}{hint})") from None
    if shipped:  # a local file named like a shipped model: say which one is used
        print(f"note: --policy {spec} loads the local file {path}; the shipped model is --policy pretrained:{shipped}",
              file=sys.stderr)
    return path


def _check_graph(path: Path, env_id: str, env_kwargs: dict[str, Any] | None, allow: bool) -> None:
    """An exported graph can be run in the env: ONNX Runtime is installed, the file is a graph with its contract, and
    the env's observation shapes and (unless ``allow``) world are the model's."""
    import gymnasium as gym

    from sb3_crowdnav.deploy import OnnxPolicy

    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        OnnxPolicy(path, env, allow_env_mismatch=allow)
    except (ImportError, OSError, ValueError) as exc:
        raise UsageError(f"--policy {path}: {exc}") from None
    finally:
        env.close()


def _check_shapes(path: Path, env_id: str, env_kwargs: dict[str, Any] | None) -> None:
    """The model's observation shapes are the env's (another ``max_humans``, another env), read without unpickling."""
    import gymnasium as gym

    from sb3_crowdnav.evaluation.runner import check_spaces
    from sb3_crowdnav.serialization import UnsafeModelFileError, safe_custom_objects

    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        model_space = safe_custom_objects(path, env).get("observation_space")
        check_spaces(model_space, env.observation_space, f"--policy {path.name}")
    except (UnsafeModelFileError, ValueError) as exc:
        raise UsageError(f"--policy: {exc}" if isinstance(exc, UnsafeModelFileError) else str(exc)) from None
    finally:
        env.close()


def _check_world(path: Path, env_id: str, env_kwargs: dict[str, Any] | None, allow: bool) -> None:
    """A usage error, before any episode, when the model at ``path`` was trained in another world than the env's
    (:func:`~sb3_crowdnav.models.world_mismatch`), unless ``allow`` (``--allow-env-mismatch``)."""
    import gymnasium as gym

    from sb3_crowdnav.models import world_mismatch

    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        mismatch = world_mismatch(path, env)
    finally:
        env.close()
    if mismatch and not allow:
        raise UsageError(f"--policy {path.name}: {mismatch}; pass --allow-env-mismatch to evaluate it there anyway")


__all__ = ["check_policy"]
