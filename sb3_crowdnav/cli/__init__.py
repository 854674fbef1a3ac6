"""The ``sb3-crowdnav`` command line: ``evaluate``, ``benchmark``, ``render``, ``train``, ``export``, ``aggregate``, ``sweep``.

Run ``sb3-crowdnav <command> --help`` for the options of each command. Policies are given as
``orca`` (``orca-constrained``), ``random`` (or ``random:SEED``), ``pretrained:NAME`` or the path
of a saved model ``.zip`` (APGValue, DQN, PPO; the algorithm is detected). Test episode ``i``
uses ``env.reset(seed=1_000_000 + i)`` (``--seed-offset``), disjoint from training seeds.
``train --variant NAME`` runs the paper's schedule of a variant; ``train --hyperparams FILE``
trains from an rl-zoo3 hyperparameter file; ``export --policy SPEC --out FILE.onnx`` writes a model's decision as
one ONNX graph, which ``evaluate --policy FILE.onnx`` runs. ``aggregate`` reads evaluations of several training seeds
and aggregates them with rliable; ``sweep GRID.yaml`` runs a grid of ``train`` runs and their evaluations on Ray.
Bad arguments exit with status 2 and a one-line message.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys

from sb3_crowdnav.cli import aggregate, evaluate, export, sweep, train
from sb3_crowdnav.cli.common import DEFAULT_ENV_ID, Parser, UsageError, common_options, env_options


def build_parser(parser_class: type[Parser] = Parser) -> argparse.ArgumentParser:
    """The ``sb3-crowdnav`` argument parser; its subcommands' parsers are of ``parser_class`` too (``sweep`` reads a
    grid's cells with one whose errors raise instead of exiting)."""
    from sb3_crowdnav.version import __version__

    parser = parser_class(prog="sb3-crowdnav", description=__doc__.split("\n\n")[0].replace("``", ""),
                    formatter_class=argparse.RawDescriptionHelpFormatter,
                    epilog="Run 'sb3-crowdnav <command> --help' for the options of a command.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="command", required=True)
    parents = [common_options(), env_options()]
    evaluate.add_parsers(sub, parents)
    train.add_parser(sub, parents)
    export.add_parser(sub, [common_options()])
    aggregate.add_parser(sub, [common_options()])
    sweep.add_parser(sub, [common_options()])
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``sb3-crowdnav`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if "env" in args and args.env is None and getattr(args, "variant", None) is None:  # --variant: its own env
        args.env = DEFAULT_ENV_ID

    from sb3_crowdnav.nn import configure_cpu

    configure_cpu(args.threads)  # small networks: one thread is fastest on shared cores; keep freed memory
    try:
        return args.func(args)
    except UsageError as exc:
        parser.exit(2, f"sb3-crowdnav {args.command}: error: {exc}\n")
    except KeyboardInterrupt:
        parser.exit(130, "interrupted\n")
    except BrokenPipeError:  # whoever read the output went away (e.g. `| head`): stop quietly, as other tools do
        with contextlib.suppress(OSError, ValueError):  # and no second error when Python flushes stdout at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except Exception as exc:  # one line, not a traceback (unless --debug)
        if args.debug:
            raise
        user_error = isinstance(exc, (ValueError, TypeError, OSError, RuntimeError))
        message = " ".join(str(exc).split()) or type(exc).__name__
        parser.exit(2 if user_error else 1, f"sb3-crowdnav {args.command}: error: {type(exc).__name__}: {message} "
                                           "(--debug shows the traceback)\n")


__all__ = ["UsageError", "build_parser", "main"]
