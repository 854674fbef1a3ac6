"""``sb3-crowdnav export``: a trained model's greedy decision as one ONNX graph (:func:`sb3_crowdnav.deploy.export_onnx`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import UsageError, check_out

POLICY_HELP = ("a shipped model, pretrained:NAME, or the path of a saved model .zip (APGValue, DQN, PPO, A2C, QRDQN, "
               "MaskablePPO)")


def add_parser(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """Add ``export`` to the subcommands ``sub``."""
    p = sub.add_parser("export", parents=parents, help="export a model's decision as one ONNX graph",
                       description="Write a trained model's whole greedy decision (for APGValue: the propagation over "
                                   "every action, the reward, the wall checks, the value network(s) and the argmax) as "
                                   "one ONNX graph, with the world contract as metadata. Run it with "
                                   "sb3_crowdnav.deploy.OnnxPolicy or 'sb3-crowdnav evaluate --policy FILE.onnx'. "
                                   "Needs the deploy extra: pip install \"sb3-crowdnav[deploy]\".")
    p.add_argument("--policy", required=True, help=POLICY_HELP)
    p.add_argument("--out", type=Path, required=True, metavar="FILE.onnx", help="the graph to write")
    # its own dest: without --env nothing is checked against an env (the command line's default env is not assumed)
    p.add_argument("--env", dest="export_env", metavar="ID",
                   help="the env the model acts in: its observation shapes and world are checked against the model's, "
                        "and its robot's radius and v_pref recorded (default: no check, the package's robot)")
    p.add_argument("--env-kwargs", dest="export_env_kwargs", metavar="DICT",
                   help="keyword arguments of --env as a Python literal, e.g. \"dict(actions='paper')\"")
    p.set_defaults(func=_cmd_export)


def _model_path(text: str) -> Path:
    """The saved model a ``--policy`` names: a shipped model (its hash checked) or a ``.zip``."""
    from sb3_crowdnav.evaluation.policy_spec import PolicySpec
    from sb3_crowdnav.models import check_pretrained, detect_algorithm, resolve_model_path

    try:
        spec = PolicySpec.parse(text, name="--policy")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not spec.is_model:
        raise UsageError(f"--policy {text!r} is not a trained model; export takes {POLICY_HELP}")
    if spec.is_onnx:
        raise UsageError(f"--policy {text!r} is an exported graph already; export takes {POLICY_HELP}")
    try:
        if spec.kind == "pretrained":
            return check_pretrained(str(spec.argument))
        path = resolve_model_path(str(spec.argument))
        detect_algorithm(path)  # a file that is no model archive is refused here
        return path
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(f"--policy: {exc}") from None


def _env(args: argparse.Namespace) -> Any:
    """The ``--env`` made with ``--env-kwargs`` (None without ``--env``)."""
    if args.export_env is None:
        if args.export_env_kwargs:
            raise UsageError("--env-kwargs needs --env (the env they configure)")
        return None
    import gymnasium as gym

    from sb3_crowdnav.cli.common import check_env, parse_env_kwargs

    kwargs = parse_env_kwargs(args.export_env_kwargs) if args.export_env_kwargs else {}
    check_env(args.export_env, kwargs)
    return gym.make(args.export_env, **kwargs)


def _cmd_export(args: argparse.Namespace) -> int:
    from sb3_crowdnav.deploy.metadata import require

    out: Path = args.out
    if out.suffix.lower() != ".onnx":
        raise UsageError(f"--out must end in .onnx, got {str(out)!r}")
    try:  # before any work: the extra's packages
        for module in ("onnx", "onnxscript", "onnxruntime"):
            require(module, "sb3-crowdnav export")
    except ImportError as exc:
        raise UsageError(str(exc)) from None
    path = _model_path(args.policy)
    check_out(out, is_file=True)
    env = _env(args)
    from sb3_crowdnav.deploy import OnnxPolicy, export_onnx

    try:
        export_onnx(path, out, env=env)
    finally:
        if env is not None:
            env.close()
    meta = OnnxPolicy(out).metadata  # the file as a robot reads it back
    world = meta.world
    inputs = ", ".join(f"{key} (B, {shape[0]})" for key, shape in meta.schema.shapes.items())
    print(f"{args.policy} -> {out} ({out.stat().st_size / 1e6:.1f} MB, ONNX opset {meta.opset})\n"
          f"  inputs (float32): {inputs}\n"
          f"  outputs: action (B,) int64, action_values (B, {world.n_actions}): {meta.kind}\n"
          f"  world: time_step={world.time_step} s, {world.kinematics}, actions={world.actions!r}, "
          f"max_acceleration={world.max_acceleration}, max_turn_rate={world.max_turn_rate}; robot radius "
          f"{meta.robot_radius} m, v_pref {meta.robot_v_pref} m/s")
    return 0
