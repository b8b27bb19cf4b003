"""The `jaxround` command: one entry point, one subcommand per job.

Penetrations on the command line are percentages (0-100), as in the paper's
tables; in config files they are shares (0-1).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from jaxround.config import ConfigError, ScenarioConfig, load_config
from jaxround.report import percent_label


class UsageError(ValueError):
    """A command-line value is wrong; reported without a traceback."""


# ------------------------------------------------------------------ argument types


def percent(text: str) -> float:
    """A penetration in percent -> share in [0, 1]."""
    try:
        x = float(text.rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= x <= 100.0:
        raise argparse.ArgumentTypeError(
            f"{text}: a penetration is a percentage, 0-100"
        )
    return x / 100.0


def percent_list(text: str) -> list[float]:
    """'0,10,...,100' or '0,50,100' -> shares."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if "..." in parts:
        i = parts.index("...")
        if i < 2 or i != len(parts) - 2:
            raise argparse.ArgumentTypeError("use 'a,b,...,z' with a step given by a,b")
        a, b, z = float(parts[0]), float(parts[1]), float(parts[-1])
        step = b - a
        if step <= 0:
            raise argparse.ArgumentTypeError(f"{text}: the step must be positive")
        values = []
        x = a
        while x <= z + 1e-9:
            values.append(x)
            x += step
        parts = [str(v) for v in values]
    shares = [percent(p) for p in parts]
    if not shares:
        raise argparse.ArgumentTypeError("no penetration given")
    return sorted(set(shares))


def positive_int(text: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if x < 1:
        raise argparse.ArgumentTypeError(f"{text}: expected at least 1")
    return x


def non_negative_int(text: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if x < 0:
        raise argparse.ArgumentTypeError(f"{text}: expected 0 or more")
    return x


# ------------------------------------------------------------------ helpers


def fresh_output_dir(path: Path, force: bool, would_write: Sequence[str]) -> Path:
    """Create `path`; refuse to overwrite any of `would_write` in it unless forced."""
    if path.exists() and not path.is_dir():
        raise UsageError(f"--out {path}: exists and is not a folder")
    clash = [name for name in would_write if (path / name).exists()]
    if clash and not force:
        raise UsageError(
            f"--out {path}: already holds {', '.join(clash)}; choose another folder "
            "or pass --force to overwrite"
        )
    path.mkdir(parents=True, exist_ok=True)
    return path


def seeds_of(cfg: ScenarioConfig, k: int) -> list[int]:
    """K consecutive seeds starting at the config's seed."""
    return [cfg.simulation.seed + i for i in range(k)]


def print_json(obj: object) -> None:
    json.dump(obj, sys.stdout, indent=2)
    sys.stdout.write("\n")


# ------------------------------------------------------------------ commands


def cmd_scenario(args: argparse.Namespace) -> None:
    from jaxround.schedule import make_schedule
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
    from jaxround.report import (
        ABSOLUTE_COLUMNS,
        TABLE3_COLUMNS,
        markdown_table,
        table_rows,
    )

    rows = table_rows({p: result["mean"]})
    print(markdown_table(TABLE3_COLUMNS, rows["table3"]))
    print(markdown_table(ABSOLUTE_COLUMNS, rows["absolute"]))


def cmd_run(args: argparse.Namespace) -> None:
    from jaxround.metrics import class_metrics, mean_over_runs
    from jaxround.parity import run_jax
    from jaxround.plots import plot_sweep
    from jaxround.report import write_json, write_tables
    from jaxround.schedule import make_schedule
    from sumo_export.evaluate import sumo_sweep
    from sumo_export.scenario import write_scenario

    cfg = load_config(args.config)
    out = fresh_output_dir(args.out, args.force, ["results.json"])
    seeds = seeds_of(cfg, 1 if args.quick else args.seeds)
    penetrations = [0.0, 0.5, 1.0] if args.quick else [i / 10 for i in range(11)]
    started = time.time()
    write_scenario(cfg, make_schedule(cfg), out / "scenario")
    say = (
        (lambda msg: None)
        if args.no_progress
        else (lambda msg: print(msg, file=sys.stderr))
    )
    say(f"[1/3] scenario files in {out / 'scenario'}")
    say(
        f"[2/3] SUMO: {len(penetrations)} penetrations x {len(seeds)} seeds "
        "(AVs drive the plain AV vType: no policy yet)"
    )
    sumo = sumo_sweep(
        cfg, penetrations, seeds, workers=args.workers,
        show_progress=not args.no_progress,
    )  # fmt: skip
    means = {p: r["mean"] for p, r in sumo.items()}
    say(f"[3/3] JAX: the all-human baseline on the same {len(seeds)} schedule(s)")
    horizon = cfg.demand.duration_s
    jax_runs = run_jax(cfg, seeds, penetration=0.0)
    jax_means = {
        0.0: mean_over_runs([class_metrics(r["records"], horizon) for r in jax_runs])
    }
    tables = write_tables(means, out, "sumo")
    write_tables(jax_means, out, "jax")
    plot_sweep(
        {"sumo": means, "jax": jax_means},
        out / "sweep.png",
        f"{cfg.name}: {len(seeds)} seed(s), AVs without policy",
    )
    results = {
        "scenario": cfg.name,
        "config_fingerprint": cfg.fingerprint(),
        "seeds": seeds,
        "policy": None,
        "sumo": {percent_label(p): m for p, m in means.items()},
        "jax": {percent_label(p): m for p, m in jax_means.items()},
        "wall_time_s": round(time.time() - started, 1),
    }
    write_json(results, out / "results.json")
    print(tables)
    j0, s0 = jax_means[0.0]["hv"], means[0.0]["hv"]
    print(
        f"all-human baseline, mean crossing time: SUMO "
        f"{s0['mean_crossing_time_s']:.2f} s, JAX {j0['mean_crossing_time_s']:.2f} s"
    )
    print(f"wrote {out / 'results.json'}, tables and {out / 'sweep.png'}")


def cmd_parity(args: argparse.Namespace) -> None:
    from jaxround.parity import parity_report

    cfg = load_config(args.config)
    report = parity_report(
        cfg, seeds_of(cfg, args.seeds), workers=args.workers,
        show_progress=not args.no_progress,
    )  # fmt: skip
    if args.json:
        print_json(report)
        return
    rows = [
        ("mean crossing time (s)", "mean_crossing_time_s"),
        ("CO2 (g/veh)", "co2_g_per_veh"),
        ("fuel (g/veh)", "fuel_g_per_veh"),
        ("arrived", "n_arrived"),
    ]
    print(f"{cfg.name}, HV only, seeds {report['seeds']}\n")
    print("| metric | JAX | SUMO | rel. error |\n|---|---|---|---|")
    for label, key in rows:
        j, s_ = report["jax"]["all"][key], report["sumo"]["all"][key]
        err = report["rel_err"][key]
        print(f"| {label} | {j:.2f} | {s_:.2f} | {100 * err:.2f}% |")
    print(
        f"\nper-vehicle crossing time: median |error| "
        f"{report['per_vehicle_median_abs_err_s']:.2f} s, "
        f"90th percentile {report['per_vehicle_p90_abs_err_s']:.2f} s, "
        f"exactly equal {100 * report['per_vehicle_exact_share']:.1f}%"
    )


def cmd_bench(args: argparse.Namespace) -> None:
    from jaxround.bench import format_benchmark, run_benchmark

    cfg = load_config(args.config)
    result = run_benchmark(cfg, progress=not args.no_progress)
    if args.json:
        print_json(result)
    else:
        print(format_benchmark(result))


# ------------------------------------------------------------------ parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxround",
        description="JAX roundabout environment, SUMO runs and the paper's evaluation.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def sumo_run_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--workers",
            type=positive_int,
            default=None,
            help="SUMO processes side by side (default: CPUs)",
        )
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.add_argument("--no-progress", action="store_true", help="no progress bar")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--config",
            default=None,
            help="scenario YAML file or built-in name (default: milan)",
        )

    p = sub.add_parser("scenario", help="write the SUMO files of a scenario")
    common(p)
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seed", type=non_negative_int, default=None, help="schedule seed")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=cmd_scenario)

    p = sub.add_parser("sumo", help="run the scenario in SUMO and print its metrics")
    common(p)
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seeds", type=positive_int, default=1, help="number of seeds")
    sumo_run_options(p)
    p.set_defaults(func=cmd_sumo)

    p = sub.add_parser("parity", help="JAX against SUMO on the same HV-only schedules")
    common(p)
    p.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    sumo_run_options(p)
    p.set_defaults(func=cmd_parity)

    p = sub.add_parser("bench", help="vehicle-steps per second: JAX batches vs SUMO")
    common(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("run", help="the main job on a scenario: tables, plots, results")
    common(p)
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    p.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    p.add_argument("--quick", action="store_true", help="1 seed, 3 penetrations")
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="SUMO processes side by side (default: CPUs)",
    )
    p.add_argument("--force", action="store_true", help="overwrite results.json")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ConfigError, UsageError) as err:
        print(f"jaxround {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
