"""Commands that run the scenario: `scenario`, `sumo`, `parity`, `bench`, `render`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxround.analysis.report import markdown_table, percent_label
from jaxround.apps.cli.arguments import (
    UsageError,
    config_option,
    drain_option,
    fresh_output_dir,
    non_negative_int,
    percent,
    positive_int,
    print_json,
    seeds_of,
    slots_option,
    sumo_run_options,
    warn_outside_at_cap,
    warn_slot_overflow,
)
from jaxround.scenario.config import load_config


def cmd_scenario(args: argparse.Namespace) -> None:
    from jaxround.scenario.schedule import make_schedule
    from sumo_export.scenario import write_scenario

    cfg = load_config(args.config)
    stem = cfg.name
    out = fresh_output_dir(
        args.out,
        args.force,
        [
            f"{stem}.net.xml",
            f"{stem}.rou.xml",
            f"{stem}.sumocfg",
            f"{stem}.schedule.npz",
        ],
    )
    seed = cfg.simulation.seed if args.seed is None else args.seed
    p = cfg.simulation.penetration if args.penetration is None else args.penetration
    cfg = cfg.with_overrides(seed=seed, penetration=p)
    schedule = make_schedule(cfg)
    files = write_scenario(cfg, schedule, out)
    print(f"wrote {files.net}\n      {files.routes}\n      {files.sumocfg}")
    print(
        f"{schedule.n_vehicles} vehicles, {schedule.n_av} AVs, seed {seed}; "
        f"open with: sumo-gui -c {files.sumocfg}"
    )


def cmd_sumo(args: argparse.Namespace) -> None:
    from sumo_export.evaluate import sumo_sweep

    cfg = load_config(args.config)
    p = cfg.simulation.penetration if args.penetration is None else args.penetration
    sweep = sumo_sweep(
        cfg,
        [p],
        seeds_of(cfg, args.seeds),
        workers=args.workers,
        show_progress=not args.no_progress,
    )
    result = sweep[p]
    if args.json:
        print_json(result)
        return
    from jaxround.analysis.report import (
        TABLE3_COLUMNS,
        absolute_columns,
        markdown_table,
        table_rows,
    )

    summary = {p: result["mean"]}
    rows = table_rows(summary)
    print(markdown_table(TABLE3_COLUMNS, rows["table3"]))
    print(markdown_table(absolute_columns(summary), rows["absolute"]))


def print_seed_errors(report: dict) -> None:
    """The parity report's errors schedule by schedule, with their interval."""
    by_seed = report["rel_err_by_seed"]
    n = len(report["seeds"])
    for label, key in (
        ("crossing time", "mean_crossing_time_s"),
        ("CO2", "co2_g_per_veh"),
    ):
        d = by_seed[key]
        if d["ci95"] is None:
            continue
        each = ", ".join("-" if e is None else f"{100 * e:+.1f}" for e in d["per_seed"])
        low, high = (100 * x for x in d["ci95"])
        print(
            f"\n{label} error by schedule (%): {each}; mean {100 * d['mean']:+.2f}%,"
            f" 95% interval over the {n} schedules [{low:+.2f}, {high:+.2f}]"
        )


def cmd_parity(args: argparse.Namespace) -> None:
    from jaxround.apps.drivers import parse_av_numbers, with_av_numbers
    from jaxround.apps.parity import parity_report

    cfg = load_config(args.config)
    try:
        cfg = with_av_numbers(cfg, parse_av_numbers(args.av or ""))
        report = parity_report(
            cfg, seeds_of(cfg, args.seeds), workers=args.workers,
            show_progress=not args.no_progress, penetration=args.penetration,
            controller=args.controller, max_vehicles=args.max_vehicles,
            drain_s=args.drain_s, crossing_leaders=args.crossing_leaders,
        )  # fmt: skip
    except ValueError as err:
        raise UsageError(str(err)) from None
    warn_slot_overflow(report, "parity")
    warn_outside_at_cap(report, "parity")
    if args.json:
        print_json(report)
        return
    rows = [
        ("mean crossing time (s)", "mean_crossing_time_s"),
        ("CO2 (g/veh)", "co2_g_per_veh"),
        ("fuel (g/veh)", "fuel_g_per_veh"),
        ("arrived", "n_arrived"),
        ("conflicts per 1,000 veh", "conflicts_per_1000_veh"),
    ]
    who = (
        "HV only"
        if args.penetration == 0
        else f"{percent_label(args.penetration)}% AVs ({report['controller']})"
    )
    print(f"{cfg.name}, {who}, seeds {report['seeds']}\n")
    print("| metric | JAX | SUMO | rel. error |\n|---|---|---|---|")
    for label, key in rows:
        j, s_ = report["jax"]["all"][key], report["sumo"]["all"][key]
        err = report["rel_err"][key]
        shown = "-" if err is None else f"{100 * err:.2f}%"
        print(f"| {label} | {j:.2f} | {s_:.2f} | {shown} |")
    if "lanes" in report:  # two-lane roads
        lanes = report["lanes"]
        err = report["lane_changes_rel_err"]
        changes = [lanes[sim]["lane_changes_per_veh"] for sim in ("jax", "sumo")]
        print(
            f"| lane changes per vehicle | {changes[0]:.3f} | {changes[1]:.3f} | "
            + ("-" if err is None else f"{100 * err:.2f}%")
            + " |"
        )
        shares = [lanes[sim]["inner_ring_share"] for sim in ("jax", "sumo")]
        if None not in shares:
            print(
                f"| inner ring lane's share of ring time | {100 * shares[0]:.1f}% | "
                f"{100 * shares[1]:.1f}% | "
                f"{report['inner_ring_share_diff_points']:.1f} points |"
            )
    print_seed_errors(report)
    print(
        f"\ncollisions: JAX {report['jax_collisions']}, SUMO "
        f"{report['sumo_collisions']}; SUMO teleports {report['sumo_teleports']}"
    )
    print(
        f"\nper-vehicle crossing time: median |error| "
        f"{report['per_vehicle_median_abs_err_s']:.2f} s, "
        f"90th percentile {report['per_vehicle_p90_abs_err_s']:.2f} s, "
        f"exactly equal {100 * report['per_vehicle_exact_share']:.1f}%"
    )
    print(
        f"not arrived by {report['cap_s']:.0f} s: JAX {report['jax_not_arrived']}, "
        f"SUMO {report['sumo_not_arrived']}; means and errors over the "
        f"{report['n_compared']} vehicles arrived in both; JAX slot overflow "
        f"{report['jax_slot_overflow']} vehicle-steps ({report['max_vehicles']} slots)"
    )
    if args.saturation or report["outside_at_cap"]:
        from jaxround.analysis.saturation import SATURATION_COLUMNS, saturation_rows

        print(
            "\npast capacity: per-leg entry rates and crossing-time quantiles, "
            "mean over seeds [95% interval]; per-vehicle errors are not the "
            "measure once queues grow (see docs/parity.md)\n"
        )
        rows = saturation_rows(report["saturation"])
        print(markdown_table(SATURATION_COLUMNS, rows), end="")


def cmd_bench(args: argparse.Namespace) -> None:
    from jaxround.apps.bench import format_benchmark, run_benchmark

    if args.batch is not None and not args.profile:
        raise UsageError("--batch: only with --profile (the benchmark runs its own)")
    if args.profile and (args.policy is not None or args.train_config is not None):
        raise UsageError("--policy, --train-config: not with --profile (no training)")
    cfg = load_config(args.config)
    if args.profile:
        from jaxround.apps.bench.profile import (
            DEFAULT_BATCH,
            format_profile,
            profile_step,
        )

        batch = args.batch or DEFAULT_BATCH
        if not args.no_progress:
            print(
                f"bench --profile: compiling and warming up {batch} roundabouts "
                "of the step, then one profiled window (about half a minute)",
                file=sys.stderr,
            )
        result = profile_step(cfg, batch=batch)
        if args.json:
            print_json(result)
        else:
            print(format_profile(result))
        return
    if args.no_training and args.policy is not None:
        raise UsageError("--policy: not with --no-training (it drives the rollouts)")
    training = None
    try:
        if not args.no_training:
            from agents.common.config import load_ppo_config

            training = load_ppo_config(args.train_config)
            if args.config is not None:
                training = training.replace(scenario=args.config)
        result = run_benchmark(
            cfg, progress=not args.no_progress, training=training, policy=args.policy
        )
    except (ValueError, FileNotFoundError) as err:
        raise UsageError(str(err)) from None
    warn_slot_overflow(result, "bench")
    if args.json:
        print_json(result)
    else:
        print(format_benchmark(result))


def cmd_render(args: argparse.Namespace) -> None:
    from jaxround.analysis.episode_movie import render_rollout

    try:
        path = render_rollout(
            args.out, scenario=args.config or "milan", seconds=args.seconds,
            every=args.every, penetration=args.penetration, seed=args.seed,
            fps=args.fps,
        )  # fmt: skip
    except ValueError as err:
        raise UsageError(str(err)) from None
    print(f"wrote {path}")


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""
    p = sub.add_parser("scenario", help="write the SUMO files of a scenario")
    config_option(p)
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seed", type=non_negative_int, default=None, help="schedule seed")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=cmd_scenario)

    p = sub.add_parser("sumo", help="run the scenario in SUMO and print its metrics")
    config_option(p)
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seeds", type=positive_int, default=1, help="number of seeds")
    sumo_run_options(p)
    p.set_defaults(func=cmd_sumo)

    p = sub.add_parser("parity", help="JAX against SUMO on the same schedules")
    config_option(p)
    p.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    p.add_argument(
        "--penetration", type=percent, default=0.0,
        help="AVs, percent (default 0)",
    )  # fmt: skip
    p.add_argument(
        "--controller", default=None, metavar="SPEC",
        help="who drives the AVs in both simulators: uncontrolled (default, "
        "their vType), accel:A, cruise:V, eco[:B], timed[:H], a lane rule "
        "after + or alone on two-lane roads (inner, outer, gap:X; e.g. "
        "eco+gap:5) or a policy file",
    )  # fmt: skip
    p.add_argument(
        "--av", default=None, metavar="NAME=V,...",
        help="the AVs' vType with these numbers in both simulators, e.g. "
        "tau=0.5,impatience=1 (tau, impatience, accel, jm_timegap_minor)",
    )  # fmt: skip
    slots_option(p)
    drain_option(p)
    p.add_argument(
        "--crossing-leaders", action=argparse.BooleanOptionalAction, default=True,
        help="two-lane roads: JAX's link leaders on the internal lanes that "
        "cross at a left entry, as SUMO's (on by default; docs/two_lane.md)",
    )  # fmt: skip
    p.add_argument(
        "--saturation", action="store_true",
        help="also print per-leg entry rates and crossing-time quantiles over "
        "seeds with intervals (printed anyway when vehicles are left outside at "
        "the cap; always in --json)",
    )  # fmt: skip
    sumo_run_options(p)
    p.set_defaults(func=cmd_parity)

    p = sub.add_parser("bench", help="vehicle-steps per second: JAX batches vs SUMO")
    config_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument(
        "--profile", action="store_true",
        help="instead: where the JAX step's time goes, phase by phase (no SUMO)",
    )  # fmt: skip
    p.add_argument(
        "--batch", type=positive_int, default=None,
        help="roundabouts stepped together in the profile (default 256)",
    )  # fmt: skip
    p.add_argument(
        "--no-training", action="store_true",
        help="skip PPO training and the policy rollouts (JAX, SUMO in the loop)",
    )  # fmt: skip
    p.add_argument(
        "--policy", type=Path, default=None, metavar="P",
        help="exported policy of the rollouts (default: a freshly initialised "
        "network of the training config; the same speed, meaningless actions)",
    )  # fmt: skip
    p.add_argument(
        "--train-config", default=None, metavar="PPO_YAML",
        help="PPO config timed (default ppo_milan; its scenario: --config if given)",
    )  # fmt: skip
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("render", help="an episode of the JAX environment as GIF/MP4")
    config_option(p)
    p.add_argument("--out", type=Path, required=True, help=".gif or .mp4 to write")
    p.add_argument("--seconds", type=float, default=120.0, help="simulated seconds")
    p.add_argument("--every", type=positive_int, default=2, help="steps per frame")
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seed", type=non_negative_int, default=0, help="schedule seed")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second")
    p.set_defaults(func=cmd_render)
