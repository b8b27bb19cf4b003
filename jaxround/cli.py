"""The `jaxround` command: one entry point, one subcommand per job.

Penetrations on the command line are percentages (0-100), as in the paper's
tables; in config files they are shares (0-1).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from jaxround.capacity import warn_slot_overflow
from jaxround.config import ConfigError, ScenarioConfig, load_config
from jaxround.pipeline import QUICK_TRAIN_STEPS
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
    return _int_at_least(text, 1, "at least 1")


def non_negative_int(text: str) -> int:
    return _int_at_least(text, 0, "0 or more")


def _int_at_least(text: str, low: int, expected: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if x < low:
        raise argparse.ArgumentTypeError(f"{text}: expected {expected}")
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
    from agents.config import load_ppo_config
    from jaxround.pipeline import TRAIN_DIR, headline, main_job

    cfg = load_config(args.config)
    train_cfg = load_ppo_config(args.train_config)
    if args.quick:
        train_cfg = train_cfg.replace(
            total_env_steps=min(train_cfg.total_env_steps, QUICK_TRAIN_STEPS)
        )
    if args.total_steps is not None:
        train_cfg = train_cfg.replace(total_env_steps=args.total_steps)
    out = fresh_output_dir(
        args.out, args.force, ["results.json", "evaluation.json", TRAIN_DIR]
    )
    seeds = seeds_of(cfg, 1 if args.quick else args.seeds)
    penetrations = [0.0, 0.5, 1.0] if args.quick else [i / 10 for i in range(11)]
    say = (
        (lambda msg: None)
        if args.no_progress
        else (lambda msg: print(msg, file=sys.stderr))
    )
    result = main_job(
        cfg, out, seeds, penetrations, train_cfg, workers=args.workers,
        progress=not args.no_progress, say=say,
    )  # fmt: skip
    warn_slot_overflow(result, "run (JAX evaluation)")
    print(result["tables"])
    print(headline(result))
    print(
        f"wrote {out / 'results.json'}, the tables and figures in {out}, the "
        f"training run in {out / TRAIN_DIR} ({result['wall_time_s']:.0f} s in all)"
    )


def cmd_parity(args: argparse.Namespace) -> None:
    from jaxround.parity import parity_report

    cfg = load_config(args.config)
    try:
        report = parity_report(
            cfg, seeds_of(cfg, args.seeds), workers=args.workers,
            show_progress=not args.no_progress, penetration=args.penetration,
            controller=args.controller, max_vehicles=args.max_vehicles,
        )  # fmt: skip
    except ValueError as err:
        raise UsageError(str(err)) from None
    warn_slot_overflow(report, "parity")
    if args.json:
        print_json(report)
        return
    rows = [
        ("mean crossing time (s)", "mean_crossing_time_s"),
        ("CO2 (g/veh)", "co2_g_per_veh"),
        ("fuel (g/veh)", "fuel_g_per_veh"),
        ("arrived", "n_arrived"),
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
        print(f"| {label} | {j:.2f} | {s_:.2f} | {100 * err:.2f}% |")
    print(
        f"\nper-vehicle crossing time: median |error| "
        f"{report['per_vehicle_median_abs_err_s']:.2f} s, "
        f"90th percentile {report['per_vehicle_p90_abs_err_s']:.2f} s, "
        f"exactly equal {100 * report['per_vehicle_exact_share']:.1f}%"
    )
    print(
        f"not arrived by {report['cap_s']:.0f} s: JAX {report['jax_not_arrived']}, "
        f"SUMO {report['sumo_not_arrived']}; JAX slot overflow "
        f"{report['jax_slot_overflow']} vehicle-steps ({report['max_vehicles']} slots)"
    )


def cmd_bench(args: argparse.Namespace) -> None:
    from jaxround.bench import format_benchmark, run_benchmark

    cfg = load_config(args.config)
    result = run_benchmark(cfg, progress=not args.no_progress)
    warn_slot_overflow(result, "bench")
    if args.json:
        print_json(result)
    else:
        print(format_benchmark(result))


def cmd_train(args: argparse.Namespace) -> None:
    from agents.config import load_trainer_config
    from agents.training import (
        ALGORITHMS,
        RUN_FILES,
        algorithm_of,
        clear_run,
        enable_compilation_cache,
        load_run_config,
        train_to_dir,
    )

    overrides: dict[str, int] = {}
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.total_steps is not None:
        overrides["total_env_steps"] = args.total_steps
    if args.resume is not None:
        out = args.resume
        if args.out is not None and args.out.resolve() != out.resolve():
            raise UsageError(
                "--out and --resume name different folders; --resume DIR alone "
                "continues the run in DIR"
            )
        saved_file = out / "config.yaml"
        if not saved_file.is_file():
            raise UsageError(f"--resume {out}: no config.yaml there, not a run folder")
        cfg = load_run_config(saved_file)
        algo = algorithm_of(cfg).name.lower()
        if args.algo is not None and args.algo != algo:
            raise UsageError(
                f"--resume {out}: the run trains with {algo}, not --algo {args.algo}"
            )
        wanted = (
            cfg if args.config is None else load_trainer_config(type(cfg), args.config)
        )
        wanted = wanted.replace(**overrides) if overrides else wanted
        saved, asked = cfg.to_dict(), wanted.to_dict()
        differ = [
            f"{k}: {saved[k]} -> {asked[k]}" for k in saved if saved[k] != asked[k]
        ]
        if differ:
            raise UsageError(
                f"--resume {out}: the run was started with another config "
                f"({'; '.join(differ)}); start a new run with --out"
            )
    else:
        if args.out is None:
            raise UsageError("give --out DIR for a new run, or --resume DIR")
        algo = args.algo or "ppo"
        cfg = load_trainer_config(ALGORITHMS[algo].config, args.config)
        cfg = cfg.replace(**overrides) if overrides else cfg
        out = fresh_output_dir(args.out, args.force, RUN_FILES)
        clear_run(out)
        (out / "config.yaml").write_text(cfg.to_yaml())
    enable_compilation_cache()
    say = (
        (lambda msg: None)
        if args.no_progress
        else (lambda msg: print(msg, file=sys.stderr))
    )
    steps = cfg.env_steps_per_update // cfg.n_envs
    say(
        f"{algo.upper()}: {cfg.num_updates} updates of {cfg.n_envs} x {steps} env "
        f"steps ({cfg.scenario}, {cfg.demand_window_s:g} s of demand), into {out}"
    )
    result = train_to_dir(
        cfg, out, resume=args.resume is not None, progress=not args.no_progress,
        say=say,
    )  # fmt: skip
    rate = result["env_steps_per_s"]
    last = result["last"]
    print(
        f"{result['updates']} updates"
        + (f", {rate:,.0f} env-steps/s" if rate else "")
        + (
            f", last return {last['episode_return']:.3f}, AV crossing time "
            f"{last['av_crossing_time_s']:.2f} s"
            if last
            else ""
        )
    )
    print(f"wrote {out / 'metrics.csv'}, {out / 'learning_curves.png'}")
    if result["policy"]:
        print(f"policy: {result['policy']} (+ .json)")


def cmd_evaluate(args: argparse.Namespace) -> None:
    from agents.evaluation import SUMMARY_COLUMNS, evaluate_policy, summary_rows
    from agents.export import load_policy
    from agents.training import enable_compilation_cache
    from jaxround.report import markdown_table, write_json, write_tables

    try:
        _, layout = load_policy(args.policy)
    except (OSError, ValueError) as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    cfg = load_config(args.config or layout.scenario or None)
    if args.sim == "sumo" and args.out is None:
        raise UsageError("--sim sumo writes tables and a figure: give --out DIR")
    out = (
        None
        if args.out is None
        else fresh_output_dir(args.out, args.force, ["evaluation.json"])
    )
    seeds = seeds_of(cfg, args.seeds)
    enable_compilation_cache()
    if args.sim == "sumo":
        evaluate_in_sumo(args, cfg, seeds, out)
        return
    try:
        summary = evaluate_policy(
            args.policy, cfg, args.penetrations, seeds, max_vehicles=args.max_vehicles
        )
    except ValueError as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    warn_slot_overflow(summary, "evaluate")
    results = summary["results"]
    by_label = {
        driver: {percent_label(p): m for p, m in per_p.items()}
        for driver, per_p in results.items()
    }
    report = {**summary, "results": by_label}
    if out is not None:
        write_json(report, out / "evaluation.json")
        write_tables(results["policy"], out, "jax_policy")
        write_tables(results["uncontrolled"], out, "jax_uncontrolled")
    if args.json:
        print_json(report)
        return
    print(
        f"{cfg.name}, seeds {seeds}, JAX; AVs driven by the policy and, as the "
        "baseline, uncontrolled (their IDM vType)\n"
    )
    print(markdown_table(SUMMARY_COLUMNS, summary_rows(results)))
    if out is not None:
        print(f"wrote {out / 'evaluation.json'} and tables")


def evaluate_in_sumo(
    args: argparse.Namespace, cfg: ScenarioConfig, seeds: list[int], out: Path
) -> None:
    """`jaxround evaluate --sim sumo`: SUMO, with the JAX figures beside."""
    from jaxround.pipeline import evaluate_everywhere, headline

    say = (lambda msg: None) if args.json else (lambda m: print(m, file=sys.stderr))
    try:
        result = evaluate_everywhere(
            cfg, args.policy, args.penetrations, seeds, out, workers=args.workers,
            progress=not args.json, say=say,
        )  # fmt: skip
    except (OSError, ValueError) as err:
        raise UsageError(f"--policy {args.policy}: {err}") from None
    warn_slot_overflow(result, "evaluate (JAX)")
    if args.json:
        print_json({k: v for k, v in result.items() if k != "tables"})
        return
    print(result["tables"])
    print(headline(result))
    print(f"wrote {out / 'evaluation.json'}, tables and sumo_policy.png in {out}")


def driver_values(text: str) -> dict[str, float]:
    """'accel=2.2,tau=1.0' -> {"accel": 2.2, "tau": 1.0}."""
    out = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, eq, value = part.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq:
            raise argparse.ArgumentTypeError(f"{part!r}: expected name=number")
    return out


def cmd_measure(args: argparse.Namespace) -> None:
    from jaxround.survey import SLOT_S, n_slots_for
    from sumo_export.measure import sumo_survey

    cfg = load_config(args.config)
    if args.set:
        cfg = cfg.with_human_drivers(**args.set)
    n_slots = args.slots or n_slots_for(cfg.demand.duration_s)
    if n_slots * SLOT_S > cfg.demand.duration_s + 1e-6:
        raise UsageError(
            f"--slots {n_slots}: {n_slots * SLOT_S:.0f} s is beyond the demand "
            f"horizon of {cfg.demand.duration_s:.0f} s"
        )
    if args.out.exists() and not args.force:
        raise UsageError(f"--out {args.out}: exists; pass --force to overwrite")
    survey = sumo_survey(cfg, seeds_of(cfg, args.seeds), n_slots, workers=args.workers)
    survey.save(args.out)
    print(f"wrote {args.out}: {n_slots} slots x {cfg.n_legs} legs, seeds "
          f"{list(survey.seeds)}, human drivers {survey.drivers}")  # fmt: skip


def cmd_calibrate(args: argparse.Namespace) -> None:
    from jaxround.calibrate import parse_param_names, run_calibration
    from jaxround.survey import load_survey

    names = parse_param_names(args.params)
    survey = load_survey(args.targets)
    cfg = load_config(args.config or survey.scenario or None)
    out = fresh_output_dir(
        args.out, args.force,
        ["calibration.json", "hv_vtype.xml", "fitted.yaml", "calibration.png"],
    )  # fmt: skip
    result = run_calibration(
        cfg, survey, names, out, starts=args.starts, iters=args.iters,
        temperature=args.temperature, learning_rate=args.lr,
        black_box=not args.no_black_box, check_sumo=not args.no_sumo_check,
        workers=args.workers, progress=not args.no_progress,
    )  # fmt: skip
    warn_slot_overflow(result, "calibrate")
    for name, fit in result["fits"].items():
        values = ", ".join(f"{k}={v:.4g}" for k, v in fit["values"].items())
        print(f"{name}: {values}")
        hours = fit["sim_s"] / 3600
        sumo = f", {fit['sumo_loss']:.4g} in SUMO" if "sumo_loss" in fit else ""
        print(f"  loss {fit['loss_exact']:.4g} (exact dynamics){sumo}, "
              f"{hours:.1f} simulated h, {fit['wall_s']:.0f} s wall")  # fmt: skip
        for where in ("param_errors", "jax_errors", "sumo_errors"):
            if where in fit:
                errs = ", ".join(f"{k} {v:.1%}" for k, v in fit[where].items()
                                 if not k.endswith("_abs"))  # fmt: skip
                print(f"  {where.replace('_', ' ')}: {errs}")
    where = "in SUMO" if result["chosen_by"] == "sumo_loss" else "in JAX"
    print(f"chosen: {result['chosen']} (lowest loss {where}); written to "
          "hv_vtype.xml, fitted.yaml")  # fmt: skip
    print(f"wrote {out}/calibration.json, hv_vtype.xml, fitted.yaml, calibration.png")


def cmd_export(args: argparse.Namespace) -> None:
    from agents.export import load_policy, policy_paths

    src_npz, src_json = policy_paths(args.run_dir)
    if not src_npz.is_file():
        raise UsageError(
            f"{args.run_dir}: no exported policy there (a finished `jaxround train` "
            "run writes policy.npz; resume an unfinished one with --resume)"
        )
    try:
        load_policy(src_npz)  # refuse a damaged file before copying it
    except (OSError, ValueError) as err:
        raise UsageError(str(err)) from None
    dst_npz, dst_json = policy_paths(args.out)
    for dst in (dst_npz, dst_json):
        if dst.exists() and not args.force:
            raise UsageError(f"--out {dst}: exists; pass --force to overwrite")
    dst_npz.parent.mkdir(parents=True, exist_ok=True)
    dst_npz.write_bytes(src_npz.read_bytes())
    dst_json.write_text(src_json.read_text())
    print(f"wrote {dst_npz} and {dst_json}")


def cmd_render(args: argparse.Namespace) -> None:
    from jaxround.render import render_rollout

    try:
        path = render_rollout(
            args.out, scenario=args.config or "milan", seconds=args.seconds,
            every=args.every, penetration=args.penetration, seed=args.seed,
            fps=args.fps,
        )  # fmt: skip
    except ValueError as err:
        raise UsageError(str(err)) from None
    print(f"wrote {path}")


# ------------------------------------------------------------------ parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxround",
        description="JAX roundabout environment, SUMO runs and the paper's evaluation.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def workers_option(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--workers",
            type=positive_int,
            default=None,
            help="SUMO processes side by side (default: CPUs)",
        )

    def sumo_run_options(p: argparse.ArgumentParser) -> None:
        workers_option(p)
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.add_argument("--no-progress", action="store_true", help="no progress bar")

    def slots_option(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--max-vehicles", type=positive_int, default=None,
            help="JAX vehicle slots M (default: the scenario's "
            "simulation.max_vehicles, else what the road holds)",
        )  # fmt: skip

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

    p = sub.add_parser("parity", help="JAX against SUMO on the same schedules")
    common(p)
    p.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    p.add_argument(
        "--penetration", type=percent, default=0.0,
        help="AVs, percent (default 0)",
    )  # fmt: skip
    p.add_argument(
        "--controller", default=None, metavar="SPEC",
        help="who drives the AVs in both simulators: uncontrolled (default, "
        "their vType), accel:A, cruise:V, eco[:B], timed[:H] or a policy file",
    )  # fmt: skip
    slots_option(p)
    sumo_run_options(p)
    p.set_defaults(func=cmd_parity)

    p = sub.add_parser("bench", help="vehicle-steps per second: JAX batches vs SUMO")
    common(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser(
        "run", help="the main job: train, export, evaluate in JAX and SUMO, tables"
    )
    common(p)
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    p.add_argument("--seeds", type=positive_int, default=2, help="number of seeds")
    p.add_argument(
        "--quick", action="store_true",
        help=f"1 seed, 3 penetrations, {QUICK_TRAIN_STEPS:,} training steps",
    )  # fmt: skip
    p.add_argument(
        "--train-config", default=None,
        help="PPO config YAML or built-in name (default: ppo_milan)",
    )  # fmt: skip
    p.add_argument(
        "--total-steps", type=positive_int, default=None,
        help="training env steps (overrides the PPO config)",
    )  # fmt: skip
    workers_option(p)
    p.add_argument("--force", action="store_true", help="overwrite an earlier run")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("train", help="train the AVs' policy with PPO or APG in JAX")
    p.add_argument(
        "--algo", choices=("ppo", "apg"), default=None,
        help="ppo (default) or apg (analytic policy gradients); --resume "
        "takes the run's own",
    )  # fmt: skip
    p.add_argument(
        "--config", default=None,
        help="trainer config YAML or built-in name (default: ppo_milan, apg_milan)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=None, help="folder of a new run")
    p.add_argument(
        "--resume", type=Path, default=None,
        help="continue the run in this folder from its last checkpoint",
    )  # fmt: skip
    p.add_argument("--seed", type=non_negative_int, default=None, help="PRNG seed")
    p.add_argument(
        "--total-steps", type=positive_int, default=None,
        help="env steps over all roundabouts (overrides the config)",
    )  # fmt: skip
    p.add_argument("--force", action="store_true", help="overwrite an earlier run")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser(
        "evaluate", help="a trained policy over penetrations, against uncontrolled AVs"
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
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", type=Path, default=None, help="also write files here")
    p.add_argument("--force", action="store_true", help="overwrite evaluation.json")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser(
        "measure",
        help="survey SUMO runs per leg and 10-minute slot (targets for calibrate)",
    )
    common(p)
    p.add_argument("--out", type=Path, required=True, help="targets JSON to write")
    p.add_argument("--seeds", type=positive_int, default=1, help="number of seeds")
    p.add_argument(
        "--slots", type=positive_int, default=None,
        help="10-minute slots from the start (default: the whole demand horizon)",
    )  # fmt: skip
    p.add_argument(
        "--set", type=driver_values, default=None,
        help="human-driver numbers to run with, e.g. accel=2.2,tau=1.0",
    )  # fmt: skip
    p.add_argument("--force", action="store_true", help="overwrite --out")
    workers_option(p)
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser(
        "calibrate",
        help="fit human-driver parameters to a survey, by gradients and by a black "
        "box; the better fit is written",
    )
    common(p)
    p.add_argument("--targets", type=Path, required=True, help="from jaxround measure")
    p.add_argument(
        "--params", default="accel,tau,jm_timegap_minor",
        help="EnvParams to fit, comma-separated (default accel,tau,jm_timegap_minor)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument("--starts", type=positive_int, default=4, help="random starts")
    p.add_argument("--iters", type=positive_int, default=30, help="Adam steps")
    p.add_argument("--lr", type=float, default=0.05, help="Adam step on log-values")
    p.add_argument(
        "--temperature", type=float, default=0.5,
        help="relaxation of the hard decisions while fitting (0: exact)",
    )  # fmt: skip
    p.add_argument("--no-black-box", action="store_true", help="skip the CEM baseline")
    p.add_argument(
        "--no-sumo-check", action="store_true",
        help="do not re-run SUMO with the fitted values",
    )  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--force", action="store_true", help="overwrite files in --out")
    workers_option(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("export", help="copy a training run's policy (npz + json)")
    p.add_argument("run_dir", type=Path, help="a `jaxround train` folder")
    p.add_argument("--out", type=Path, required=True, help="policy.npz to write")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("render", help="an episode of the JAX environment as GIF/MP4")
    common(p)
    p.add_argument("--out", type=Path, required=True, help=".gif or .mp4 to write")
    p.add_argument("--seconds", type=float, default=120.0, help="simulated seconds")
    p.add_argument("--every", type=positive_int, default=2, help="steps per frame")
    p.add_argument("--penetration", type=percent, default=None, help="AVs, percent")
    p.add_argument("--seed", type=non_negative_int, default=0, help="schedule seed")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second")
    p.set_defaults(func=cmd_render)

    from jaxround.study.cli import add_study_parser

    add_study_parser(sub)
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
