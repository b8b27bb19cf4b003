"""The `search` command: the best constant AV setting and a state-dependent
controller against it (`jaxround.apps.search`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from jaxround.apps.cli.arguments import (
    UsageError,
    config_option,
    fresh_output_dir,
    percent,
    positive_int,
    slots_option,
    workers_option,
)
from jaxround.scenario.config import load_config

#: First seed of the search's schedules, and of the evaluation's.
SEARCH_SEED, EVAL_SEED = 200, 100
RESULTS = ("search.json", "search.png", "best_constant.json")


def positive_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not x > 0.0:
        raise argparse.ArgumentTypeError(f"{text}: expected a number > 0")
    return x


def non_negative_float(text: str) -> float:
    x = positive_float(text) if text.strip() not in ("0", "0.0") else 0.0
    return x


def shares(text: str) -> tuple[float, ...]:
    """'0.4,0.1,0.4,0.1' -> shares that sum to 1."""
    try:
        values = tuple(float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected numbers a,b,..."
        ) from None
    if min(values) < 0 or abs(sum(values) - 1.0) > 1e-6:
        raise argparse.ArgumentTypeError(f"{text}: shares must be >= 0 and sum to 1")
    return values


def _limit_text(limit: str | float | None) -> str:
    return (
        "none" if limit is None else limit if isinstance(limit, str) else f"{limit:g}"
    )


def search_command(args: argparse.Namespace) -> str:
    """The ``jaxround search`` command of these options, every one spelled
    out (the output folder as DIR), so that it regenerates the result."""
    parts = [
        "jaxround search --out DIR", f"--config {args.config or 'milan'}",
        f"--penetration {100 * args.penetration:g}", f"--window-s {args.window_s:g}",
        f"--demand-scale {args.demand_scale:g}",
        f"--search-seeds {args.search_seeds}", f"--eval-seeds {args.eval_seeds}",
        f"--population {args.population}", f"--generations {args.generations}",
        f"--state-generations {args.state_generations or args.generations}",
        f"--time-weight {args.time_weight:g}", f"--co2-weight {args.co2_weight:g}",
        "--charge-exit" if args.charge_exit else "--no-charge-exit",
        f"--conflict-weight {args.conflict_weight:g}",
        f"--conflict-limit {_limit_text(args.conflict_limit)}",
    ]  # fmt: skip
    if args.origin_share is not None:
        parts.append("--origin-share " + ",".join(f"{x:g}" for x in args.origin_share))
    if args.max_vehicles is not None:
        parts.append(f"--max-vehicles {args.max_vehicles}")
    return " ".join(parts)


def cmd_search(args: argparse.Namespace) -> None:
    from jaxround.analysis.search_plot import plot_front
    from jaxround.analysis.setting_search import Objective, search_scenario
    from jaxround.apps.search import (
        SearchBudget,
        front_table,
        run_search,
        summary,
        sumo_recheck,
    )
    from jaxround.envs.supported import check_jax_lanes

    check_jax_lanes(load_config(args.config))  # before JAX or SUMO runs
    if args.origin_share is not None:
        n_legs = load_config(args.config).n_legs
        if len(args.origin_share) != n_legs:
            raise UsageError(
                f"--origin-share: {len(args.origin_share)} shares for {n_legs} legs"
            )
    cfg = search_scenario(
        load_config(args.config), args.window_s, args.demand_scale, args.origin_share
    )
    if args.time_weight == 0 and args.co2_weight == 0:
        raise UsageError("--time-weight and --co2-weight are both 0")
    out = fresh_output_dir(args.out, False, RESULTS)
    budget = SearchBudget(
        args.population, args.generations, args.state_generations or args.generations
    )
    objective = Objective(
        args.time_weight, args.co2_weight, args.charge_exit, args.conflict_weight
    )
    search_seeds = list(range(SEARCH_SEED, SEARCH_SEED + args.search_seeds))
    eval_seeds = list(range(EVAL_SEED, EVAL_SEED + args.eval_seeds))
    result = run_search(
        cfg, args.penetration, search_seeds, eval_seeds, budget, objective,
        args.max_vehicles, conflict_limit=args.conflict_limit,
    )  # fmt: skip
    if args.sumo:
        result["sumo"] = sumo_recheck(
            cfg, args.penetration, eval_seeds, result["best_constant"], objective,
            args.workers,
        )  # fmt: skip
    (out / "search.json").write_text(json.dumps(result, indent=1))
    from jaxround.apps.search_best_constant import best_constant_file

    best = best_constant_file(result, search_command(args))
    (out / "best_constant.json").write_text(json.dumps(best, indent=1) + "\n")
    plot_front(result, out / "search.png")
    print("front of the constants scored (search seeds):")
    print(front_table(result))
    print(summary(result))
    if args.sumo:
        s = result["sumo"]
        print(
            f"SUMO, best constant vs vType: time "
            f"{100 * s['paired']['crossing_time_s']['rel_diff']:+.2f}%, CO2 "
            f"{100 * s['paired']['co2_g']['rel_diff']:+.2f}%, objective "
            f"{100 * s['objective']['rel_diff']:+.2f}%"
        )
    print(
        f"wrote {out / 'search.json'}, {out / 'search.png'} and "
        f"{out / 'best_constant.json'} ({where_to_copy(result)})"
    )
    limit = result.get("conflict_limit_per_1000")
    found = result["eval"]["constant"]["conflicts_per_1000"]
    if limit is not None and found > limit:
        print(
            f"warning: on the evaluation seeds the best constant has {found:.1f} "
            f"near-conflicts per 1,000 vehicles, above the limit of {limit:.1f} "
            "it was held to on the search seeds (more --search-seeds or a longer "
            "--window-s make the limit hold more widely)",
            file=sys.stderr,
        )
    worse = result["constant_vs_vtype"]["rel_diff"]
    if worse > 0:  # a baseline weaker than doing nothing flatters a policy
        print(
            f"warning: the best constant's objective is {100 * worse:.1f}% worse "
            "than the AVs' own vType on the evaluation seeds: the vType is the "
            "stronger baseline. Search longer (--population, --generations) "
            "before using best_constant.json as a baseline",
            file=sys.stderr,
        )


def where_to_copy(result: dict) -> str:
    """Where a search's best_constant.json goes to be a built-in baseline:
    the scenario's name at 100% AVs, with the penetration otherwise."""
    name, percent = result["scenario"], round(100 * result["penetration"])
    if percent == 100:
        return f"copy it to configs/best_constant/{name}.json for the main job"
    return (
        f"copy it to configs/best_constant/{name}_p{percent}.json and pass "
        f"--best-constant {name}_p{percent}"
    )


def conflict_limit(text: str) -> str | float | None:
    """--conflict-limit: 'vtype', 'none' or a number of conflicts per 1,000."""
    if text in ("vtype", "none"):
        return None if text == "none" else text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected 'vtype', 'none' or conflicts per 1,000 vehicles"
        ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text}: expected at least 0")
    return value


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add the `search` subcommand to `sub`."""
    p = sub.add_parser(
        "search",
        help="search the best constant AV setting (CMA-ES in JAX) and a "
        "state-dependent controller against it",
    )
    config_option(p)
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument(
        "--penetration", type=percent, default=1.0, help="AVs in percent (default 100)"
    )
    p.add_argument(
        "--window-s",
        type=positive_float,
        default=600.0,
        help="seconds of demand per episode, at the config's rate (default 600)",
    )
    p.add_argument(
        "--demand-scale",
        type=positive_float,
        default=1.0,
        help="factor on the vehicles per second (default 1)",
    )
    p.add_argument(
        "--origin-share",
        type=shares,
        default=None,
        help="share of vehicles entering at each leg, e.g. "
        "0.55,0.05,0.35,0.05 (default: the config's)",
    )
    p.add_argument(
        "--search-seeds",
        type=positive_int,
        default=4,
        help=f"schedules the search scores on (seeds {SEARCH_SEED}..)",
    )
    p.add_argument(
        "--eval-seeds",
        type=positive_int,
        default=10,
        help=f"held-out schedules of the final check (seeds {EVAL_SEED}..)",
    )
    p.add_argument(
        "--population",
        type=positive_int,
        default=12,
        help="settings CMA-ES scores per generation (default 12)",
    )
    p.add_argument(
        "--generations",
        type=positive_int,
        default=8,
        help="CMA-ES generations of the constant search (default 8)",
    )
    p.add_argument(
        "--state-generations",
        type=positive_int,
        default=None,
        help="generations of the controller's search (default --generations)",
    )
    p.add_argument(
        "--time-weight",
        type=non_negative_float,
        default=1.0,
        help="cost of a vehicle-second (default 1)",
    )
    p.add_argument(
        "--co2-weight",
        type=non_negative_float,
        default=0.5,
        help="cost of a gram of CO2 (default 0.5)",
    )
    p.add_argument(
        "--charge-exit",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="add to each vehicle's time and CO2 what it still owes for leaving "
        "below the speed limit (jaxround.analysis.exit_debt; default on: "
        "without it, leaving slowly defers CO2 past the network's edge and "
        "scores as a saving)",
    )
    p.add_argument(
        "--conflict-weight",
        type=non_negative_float,
        default=0.0,
        help="cost of a near-conflict per vehicle of the pair, SUMO's SSM count "
        "(default 0)",
    )
    p.add_argument(
        "--conflict-limit",
        type=conflict_limit,
        default="vtype",
        help="constraint: conflicts per 1,000 vehicles no more than this; "
        "'vtype' (default): no more than the AVs' own vType uncontrolled on the "
        "search seeds; 'none': no constraint",
    )
    p.add_argument(
        "--sumo",
        action="store_true",
        help="re-check the vType and the best constant in SUMO on the evaluation seeds",
    )
    slots_option(p)
    workers_option(p)
    p.set_defaults(func=cmd_search)  # fmt: skip
