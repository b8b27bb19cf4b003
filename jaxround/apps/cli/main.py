"""The `jaxround` command: one entry point, one subcommand per job.

The subcommands live in `simulate`, `training`, `evaluation`, `calibration`,
`search`, `safety` and `jaxround.study.cli`; each module adds its own parsers.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from jaxround.apps.cli import (
    calibration,
    evaluation,
    safety,
    search,
    simulate,
    training,
)
from jaxround.apps.cli.arguments import UsageError
from jaxround.scenario.config import ConfigError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxround",
        description="JAX roundabout environment, SUMO runs and the paper's evaluation.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    training.add_parsers(sub)
    evaluation.add_parsers(sub)
    simulate.add_parsers(sub)
    calibration.add_parsers(sub)
    search.add_parsers(sub)
    safety.add_parsers(sub)
    from jaxround.study.cli import add_study_parser

    add_study_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        use_executor_of(args)
        args.func(args)
    except (ConfigError, UsageError) as err:
        print(f"jaxround {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 0


def use_executor_of(args: argparse.Namespace) -> None:
    """Send this command's SUMO runs where ``--executor`` says, checked before
    any work (`sumo_export.executors`)."""
    if getattr(args, "executor", "local") == "local":
        return
    from sumo_export.executors import use_executor

    try:
        use_executor(args.executor)
    except ValueError as err:
        raise UsageError(f"--executor: {err}") from None


if __name__ == "__main__":
    sys.exit(main())
