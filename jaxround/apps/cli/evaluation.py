"""The `evaluate` command: a trained policy over penetrations, beside
uncontrolled AVs and the best constant AV setting, in JAX or in SUMO."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxround.analysis.report import percent_label
from jaxround.apps.cli.arguments import (
    UsageError,
    best_constant_of,
    best_constant_option,
    drain_option,
    fresh_output_dir,
    percent_list,
    positive_int,
    print_json,
    score_scale_option,
    seeds_of,
    slots_option,
    warn_outside_at_cap,
    warn_slot_overflow,
    workers_option,
)
from jaxround.scenario.best_constant import BestConstant
from jaxround.scenario.config import ScenarioConfig, load_config


def evaluate_in_sumo(
    args: argparse.Namespace,
    cfg: ScenarioConfig,
    seeds: list[int],
    out: Path,
    constant: BestConstant | None,
) -> None:
    """`jaxround evaluate --sim sumo`: SUMO, with the JAX figures beside."""
    from jaxround.apps.pipeline import evaluate_everywhere, headline

    say = (lambda msg: None) if args.json else (lambda m: print(m, file=sys.stderr))
    try:
        result = evaluate_everywhere(
            cfg, args.policy, args.penetrations, seeds, out, workers=args.workers,
            progress=not args.json, say=say, drain_s=args.drain_s, constant=constant,
        )  # fmt: skip
    except (OSError, ValueError) as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    warn_slot_overflow(result, "evaluate (JAX)")
    warn_outside_at_cap(result, "evaluate")
    if args.json:
        print_json({k: v for k, v in result.items() if k != "tables"})
        return
    print(result["tables"])
    print(headline(result))
    print(f"wrote {out / 'evaluation.json'}, tables and sumo_policy.png in {out}")


def cmd_evaluate(args: argparse.Namespace) -> None:
    from agents.common.compilation import enable_compilation_cache
    from agents.common.evaluation import SUMMARY_COLUMNS, evaluate_policy, summary_rows
    from agents.common.export import load_policy
    from jaxround.analysis.report import markdown_table, write_json, write_tables
    from jaxround.envs.supported import check_jax_lanes

    try:
        _, layout = load_policy(args.policy)
    except (OSError, ValueError) as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    cfg = load_config(args.config or layout.scenario or None)
    check_jax_lanes(cfg)  # before SUMO or JAX runs: two-lane exits are SUMO's only
    if args.sim == "sumo" and args.out is None:
        raise UsageError("--sim sumo writes tables and a figure: give --out DIR")
    constant = best_constant_of(args.best_constant, cfg)
    out = (
        None
        if args.out is None
        else fresh_output_dir(args.out, args.force, ["evaluation.json"])
    )
    seeds = seeds_of(cfg, args.seeds)
    enable_compilation_cache()
    if args.sim == "sumo":
        evaluate_in_sumo(args, cfg, seeds, out, constant)
        return
    try:
        summary = evaluate_policy(
            args.policy, cfg, args.penetrations, seeds, max_vehicles=args.max_vehicles,
            drain_s=args.drain_s, score_scale=args.score_scale, constant=constant,
            progress=not args.json,
        )  # fmt: skip
    except ValueError as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    warn_slot_overflow(summary, "evaluate")
    warn_outside_at_cap(summary, "evaluate")
    results = summary["results"]
    by_label = {
        driver: {percent_label(p): m for p, m in per_p.items()}
        for driver, per_p in results.items()
    }
    report = {**summary, "results": by_label}
    if constant is not None:
        report["best_constant"] = {**constant.to_dict(), "source": constant.source}
    if out is not None:
        write_json(report, out / "evaluation.json")
        scale = summary["score_scale"]
        for driver, per_p in results.items():
            write_tables(per_p, out, f"jax_{driver}", scale)
    if args.json:
        print_json(report)
        return
    others = "uncontrolled (their IDM vType)"
    if constant is not None:
        others += f" and the best constant ({constant.describe()})"
    print(
        f"{cfg.name}, seeds {seeds}, JAX; AVs driven by the policy and, as "
        f"baselines, {others}\n"
    )
    print(markdown_table(SUMMARY_COLUMNS, summary_rows(results)))
    if out is not None:
        print(f"wrote {out / 'evaluation.json'} and tables")


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add the `evaluate` subcommand to `sub`."""
    p = sub.add_parser(
        "evaluate",
        help="a trained policy over penetrations, against uncontrolled AVs and "
        "the best constant",
    )
    p.add_argument(
        "--config", default=None,
        help="scenario YAML or built-in name (default: the policy's scenario)",
    )  # fmt: skip
    p.add_argument(
        "--policy", type=Path, required=True,
        help="policy.npz / policy.json, or a training folder",
    )  # fmt: skip
    p.add_argument(
        "--sim", choices=("jax", "sumo"), default="jax",
        help="jax (default), or sumo: SUMO through libsumo, JAX figures beside",
    )  # fmt: skip
    workers_option(p)
    p.add_argument(
        "--penetrations", type=percent_list, default=percent_list("0,10,...,100"),
        help="AV shares in percent, e.g. 0,10,...,100 (the default) or 0,50,100",
    )  # fmt: skip
    p.add_argument("--seeds", type=positive_int, default=1, help="number of seeds")
    slots_option(p)
    drain_option(p)
    score_scale_option(p)
    best_constant_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", type=Path, default=None, help="also write files here")
    p.add_argument("--force", action="store_true", help="overwrite evaluation.json")
    p.set_defaults(func=cmd_evaluate)
