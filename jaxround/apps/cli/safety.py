"""Commands about near-conflicts: `conflicts`."""

from __future__ import annotations

import argparse

from jaxround.apps.cli.arguments import (
    config_option,
    percent,
    positive_int,
    print_json,
    seeds_of,
    workers_option,
)
from jaxround.scenario.config import load_config


def cmd_conflicts(args: argparse.Namespace) -> None:
    from jaxround.apps.conflict_sweep import conflict_sweep, sweep_table

    cfg = load_config(args.config)
    seeds = seeds_of(cfg, args.seeds)
    say = (lambda _: None) if args.json else print
    rows = conflict_sweep(cfg, seeds, args.penetration, workers=args.workers, say=say)
    if args.json:
        print_json({"scenario": cfg.name, "seeds": seeds,
                    "penetration": args.penetration, "rows": rows})  # fmt: skip
        return
    print(f"\n{cfg.name}, {args.penetration * 100:g}% AVs, seeds {seeds}\n")
    print(sweep_table(rows))


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""
    p = sub.add_parser(
        "conflicts",
        help="near-conflicts against the AVs' tau and impatience, JAX and SUMO",
    )
    config_option(p)
    p.add_argument("--penetration", type=percent, default=1.0,
                   help="AVs, percent (default 100)")  # fmt: skip
    p.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    workers_option(p)
    p.set_defaults(func=cmd_conflicts)
