"""Shared pieces of the command line: the one-line-error parser, argument types, env options, usage errors."""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from sb3_crowdnav.evaluation.crowd_spec import GRAMMAR as CROWD_GRAMMAR
from sb3_crowdnav.evaluation.crowd_spec import CrowdSpec
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import DEFAULT_ENV_ID, LOOKAHEAD_KEYS
from sb3_crowdnav.sim.validation import check_int, check_positive, check_probability


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (no usage block), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_command(sub: Any, name: str, parents: list[argparse.ArgumentParser], doc: str, summary: str) -> Any:
    """Add the subcommand ``name`` to ``sub``: ``summary`` in the command list, and its ``--help`` description the
    command module's docstring ``doc`` as plain text (the reStructuredText markup of the API docs taken out)."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", doc).replace("``", "")
    return sub.add_parser(name, parents=parents, help=summary, description=" ".join(text.split()))


def _argument_type(convert: Callable[[str], Any], check: Callable[[str, Any], None], allowed: str):
    """An argparse type: ``convert`` the text, then ``check`` it with a validator of :mod:`sb3_crowdnav.sim.validation`.

    argparse names the option itself, so the error says only ``allowed`` and the text given.
    """

    def parse(text: str) -> Any:
        try:
            value = convert(text)
            check("value", value)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}") from None
        return value

    return parse


positive_int = _argument_type(int, lambda name, value: check_int(name, value, 1), "a positive integer")
nonneg_int = _argument_type(int, lambda name, value: check_int(name, value, 0), "an integer >= 0")
positive_float = _argument_type(float, check_positive, "a finite number > 0")
probability = _argument_type(float, check_probability, "a number in [0, 1]")


def env_options() -> argparse.ArgumentParser:
    p = Parser(add_help=False)
    g = p.add_argument_group("environment")
    g.add_argument("--env", help=f"Gymnasium env id (default: {DEFAULT_ENV_ID}; train --variant: the variant's env)")
    g.add_argument("--humans", "--num-humans", dest="humans", type=nonneg_int, metavar="N",
                   help="number of pedestrians (env default: 6)")
    g.add_argument("--max-humans", type=positive_int, metavar="N",
                   help="observation capacity; must match a trained model's (env default: 10)")
    g.add_argument("--reward", choices=("crowdnav", "comfort", "comfort_angular"),
                   help="reward function (env default: crowdnav)")
    g.add_argument("--visible", action="store_true", help="pedestrians see and avoid the robot")
    g.add_argument("--kinematics", choices=("unicycle", "holonomic"), help="robot kinematics (env default: unicycle)")
    g.add_argument("--crowd", nargs="+", metavar="SPEC",
                   help=f"the crowd model that moves the people: {CROWD_GRAMMAR} (env default: orca); benchmark takes "
                        "several and prints one table policy x crowd")
    g.add_argument("--human-policy", choices=("orca", "linear"), help="the old name of --crowd orca / linear")
    g.add_argument("--env-kwargs", metavar="DICT",
                   help="more env keyword arguments as a Python literal, e.g. \"dict(time_limit=30)\"")
    return p


def common_options() -> argparse.ArgumentParser:
    p = Parser(add_help=False)
    # the command line owns the process: it sets torch's threads once, at start (the algorithms never do)
    p.add_argument("--threads", type=positive_int, default=1,
                   help="torch threads of this process and of each worker or learner process (default: 1)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    return p


def progress_enabled(args: argparse.Namespace) -> bool:
    """``--progress``, or whether stderr is a terminal."""
    return sys.stderr.isatty() if args.progress is None else bool(args.progress)


class UsageError(Exception):
    """Bad user input found after parsing; reported in one line with exit status 2."""


def crowd_specs(args: argparse.Namespace) -> list[CrowdSpec]:
    """The parsed ``--crowd`` specs (none without ``--crowd``); the syntax only: :func:`check_crowd` makes the env."""
    specs = []
    for text in getattr(args, "crowd", None) or ():
        try:
            specs.append(CrowdSpec.parse(text, name="--crowd"))
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    return specs


def check_crowd(env_id: str, kwargs: dict[str, Any], spec: CrowdSpec) -> dict[str, Any]:
    """The env's keyword arguments ``kwargs`` in crowd ``spec``, the env made once with them: a model that is not
    registered, or a bad setting, is a usage error naming ``--crowd`` and what the env allows."""
    import gymnasium as gym

    import sb3_crowdnav  # noqa: F401  (registers the envs)

    crowd_kwargs = {**kwargs, **spec.env_kwargs()}
    try:
        gym.make(env_id, **crowd_kwargs).close()
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--crowd {str(spec)!r}: {exc}") from None
    return crowd_kwargs


def single_crowd(args: argparse.Namespace) -> CrowdSpec | None:
    """The one ``--crowd`` of a command that runs in one crowd (None without ``--crowd``), for :func:`check_env`."""
    specs = crowd_specs(args)
    return specs[0] if len(specs) == 1 else None


def parse_env_kwargs(text: str) -> dict[str, Any]:
    """``--env-kwargs``: a Python literal of a mapping, read by
    :func:`~sb3_crowdnav.training.hyperparams.safe_eval` (literals and ``dict(...)`` only: no code runs)."""
    from sb3_crowdnav.training.hyperparams import safe_eval

    try:
        kwargs = safe_eval(text, {"dict": dict})
    except ValueError as exc:
        raise UsageError(f"--env-kwargs: {exc} (write a mapping as \"dict(time_limit=30)\" or "
                         "\"{'time_limit': 30}\")") from None
    if not isinstance(kwargs, dict):
        raise UsageError(f"--env-kwargs must be a dict, got {text!r}")
    return kwargs


def env_kwargs_from_args(args: argparse.Namespace, crowd: bool = True) -> dict[str, Any]:
    """The env's keyword arguments of the env options; with ``crowd``, also the one ``--crowd`` (more are refused:
    only ``benchmark`` compares crowds, and it reads them with :func:`crowd_specs`)."""
    kwargs: dict[str, Any] = parse_env_kwargs(args.env_kwargs) if args.env_kwargs else {}
    flags = {"num_humans": ("--humans", args.humans), "max_humans": ("--max-humans", args.max_humans),
             "reward": ("--reward", args.reward), "kinematics": ("--kinematics", args.kinematics),
             "human_policy": ("--human-policy", args.human_policy),
             "robot_visible": ("--visible", True if args.visible else None)}
    for key, (flag, value) in flags.items():
        if value is None:
            continue
        if key in kwargs:  # one setting from two places: neither silently wins
            raise UsageError(f"{flag} and --env-kwargs {key} both set {key}; give it once")
        kwargs[key] = value
    specs = crowd_specs(args)
    if specs:
        given = [name for name in ("crowd", "crowd_kwargs", "human_policy") if name in kwargs]
        if given:
            option = "--human-policy" if args.human_policy is not None else f"--env-kwargs {given[0]}"
            raise UsageError(f"--crowd and {option} both set the crowd; give it once, with --crowd")
    if specs and crowd:
        if len(specs) > 1:
            raise UsageError(f"--crowd takes one crowd model here, got {len(specs)}; "
                             "'sb3-crowdnav benchmark --crowd A B ...' compares several")
        kwargs.update(specs[0].env_kwargs())
    return kwargs


def check_env(env_id: str, kwargs: dict[str, Any], crowd: CrowdSpec | None = None) -> None:
    """The env can be made with these options, and it is one of this package's crowd envs; with ``crowd`` (the
    ``--crowd`` among ``kwargs``), the other options are checked first and an error of the crowd's names ``--crowd``."""
    import gymnasium as gym

    if crowd is not None:
        base = {k: v for k, v in kwargs.items() if k not in ("crowd", "crowd_kwargs")}
        check_env(env_id, base)
        check_crowd(env_id, kwargs, crowd)
        return

    import sb3_crowdnav  # noqa: F401  (registers the envs)

    try:
        env = gym.make(env_id, **kwargs)
    except gym.error.Error as exc:
        raise UsageError(f"--env: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise UsageError(f"bad environment options: {exc}") from None
    crowd = hasattr(env.unwrapped, "scene")
    env.close()
    if not crowd:
        from sb3_crowdnav import ENV_IDS, WAREHOUSE_ENV_IDS

        raise UsageError(f"--env {env_id} is not a crowd-navigation env; use one of "
                         f"{', '.join([*ENV_IDS, *WAREHOUSE_ENV_IDS])}")


def check_out(path: Path, option: str = "--out", is_file: bool = False) -> None:
    """``option`` can be written: its folder (or, for a file, the file's folder) exists or can be made, and is
    writable; found before any work, not after an hour of it."""
    folder = path.parent if is_file else path
    if is_file and path.is_dir():
        raise UsageError(f"{option} {str(path)!r} is a folder; give a file name")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{option} {str(folder)!r} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".sb3_crowdnav_write_test_{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"{option} {str(folder)!r} cannot be written: {exc.strerror or exc}") from None


def add_lookahead_options(group: Any, acting: str, finished: str, defaults: dict[str, str]) -> None:
    """The five options of a value model's lookahead (APGValue), the same flags, types and choices in every command
    that sets them: ``acting`` names the lookahead that ``--pedestrian-model`` and ``--stopping-check`` set,
    ``finished`` the one that ``--planning-depth``, ``--planning-width`` and ``--cap-values`` set, and ``defaults``
    what each keeps when not given (by its ``LOOKAHEAD_KEYS`` name), as the help says it."""
    from sb3_crowdnav.training.schedule import PEDESTRIAN_MODELS

    group.add_argument("--pedestrian-model", choices=PEDESTRIAN_MODELS,
                       help=f"the pedestrians in the reward of {acting}: constant_velocity, or cautious (the worse of "
                            f"moving on and standing still) (default: {defaults['pedestrian_model']})")
    group.add_argument("--stopping-check", action=argparse.BooleanOptionalAction, default=None,
                       help=f"{acting} also charges the actions the robot cannot brake from at its max_acceleration "
                            f"(a world with an acceleration limit only) (default: {defaults['stopping_check']})")
    group.add_argument("--planning-depth", type=positive_int, metavar="D",
                       help=f"the steps {finished} searches before V (1: the paper's one-step lookahead; the cost "
                            f"grows as the distinct successors to the power D) (default: {defaults['planning_depth']})")
    group.add_argument("--planning-width", type=positive_int, metavar="K",
                       help=f"with a depth > 1, {finished} searches only the best K actions of each step deeper, by "
                            f"their one-step Q (default: {defaults['planning_width']})")
    group.add_argument("--cap-values", action=argparse.BooleanOptionalAction, default=None,
                       help=f"{finished} caps V at the largest return a state can have, also on the paper's open floor "
                            f"(--no-cap-values: never) (default: {defaults['cap_values']})")


def lookahead_settings(args: argparse.Namespace, spec: PolicySpec | None = None) -> dict[str, Any] | None:
    """The lookahead settings ``evaluate`` / ``benchmark`` were given (``--pedestrian-model``, ``--stopping-check``,
    ``--planning-depth``; None: none), or those ``spec`` acts with: the settings for a value model (APGValue, shipped
    or a ``.zip``), None for another policy (ORCA, a DQN, an ONNX graph: its lookahead is in the graph)."""
    given = {key: getattr(args, key) for key in LOOKAHEAD_KEYS if getattr(args, key, None) is not None}
    if not given or spec is None:
        return given or None
    from sb3_crowdnav.models import PRETRAINED, detect_algorithm

    algo = PRETRAINED.get(str(spec.argument)) if spec.kind == "pretrained" else \
        detect_algorithm(str(spec.argument)) if spec.is_model and not spec.is_onnx else None
    return given if algo == "apg_value" else None


def check_lookahead(args: argparse.Namespace, specs: list[PolicySpec]) -> None:
    """:class:`UsageError` when lookahead settings are given and no policy of ``specs`` is a value model."""
    given = lookahead_settings(args)
    if given and not any(lookahead_settings(args, spec) for spec in specs):
        raise UsageError(f"{' / '.join('--' + k.replace('_', '-') for k in given)}: set the lookahead of value models "
                         "(APGValue, a .zip); none of the policies given is one")
