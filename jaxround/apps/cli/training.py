"""Commands around the policy: `run` (the main job), `train`, `export` (`evaluate`
lives in `jaxround.apps.cli.evaluation`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from jaxround.apps.cli.arguments import (
    UsageError,
    best_constant_of,
    best_constant_option,
    config_option,
    fresh_output_dir,
    non_negative_int,
    positive_int,
    seeds_of,
    warn_outside_at_cap,
    workers_option,
)
from jaxround.apps.pipeline import QUICK_TRAIN_STEPS
from jaxround.scenario.config import ScenarioConfig, load_config

#: The main job's training recipe when no --train-config is given, by the
#: scenario's lanes: one lane on every road, two somewhere.
DEFAULT_TRAINING = {False: "ppo_milan", True: "ppo_two_lane"}


def main_job_training(
    config: str | None, cfg: ScenarioConfig, train_config: str | None
) -> tuple[Any, Any]:
    """The main job's PPO config and what ``n_envs: auto`` chose for it.

    Without `train_config`, `DEFAULT_TRAINING`'s recipe trains on the
    scenario evaluated (`config`, a built-in name or a file, kept as an
    absolute path so that the run's config.yaml resumes from anywhere).

    Raises:
        UsageError: `train_config` trains on other roads or drivers than
            `cfg`'s (its policy could not be evaluated there), before any
            training.
    """
    from agents.common.config import PPOConfig, load_trainer_config_and_choice

    source = train_config or DEFAULT_TRAINING[bool(cfg.network.multi_lane_keys())]
    train_cfg, choice = load_trainer_config_and_choice(PPOConfig, source)
    if train_config is None and config is not None:
        path = Path(config)
        is_file = path.suffix in (".yaml", ".yml") or path.exists()
        train_cfg = train_cfg.replace(
            scenario=str(path.resolve()) if is_file else config
        )
    trained_on, scenario = train_cfg.base_scenario(), train_cfg.scenario
    trained_roads = trained_on.roads_and_drivers_fingerprint()
    if trained_roads != cfg.roads_and_drivers_fingerprint():
        where = "" if scenario == trained_on.name else f" ({scenario})"
        raise UsageError(
            f"--train-config {train_config}: it trains on scenario "
            f"{trained_on.name!r}{where}, whose roads or drivers "
            f"are not --config {cfg.name!r}'s, so its policy could not be "
            "evaluated there; set its `scenario:` to the same scenario, or leave "
            f"--train-config out ({DEFAULT_TRAINING[False]}'s recipe on one-lane "
            f"roads, {DEFAULT_TRAINING[True]}'s on two lanes, trained on --config)"
        )
    return train_cfg, choice


def cmd_run(args: argparse.Namespace) -> None:
    from agents.common.device_batch import CPU_N_ENVS
    from jaxround.apps.pipeline import TRAIN_DIR, headline, main_job
    from jaxround.envs.supported import check_jax_lanes

    cfg = load_config(args.config)
    check_jax_lanes(cfg)  # before anything runs: two-lane exits are SUMO's only
    constant = best_constant_of(args.best_constant, cfg)
    train_cfg, choice = main_job_training(args.config, cfg, args.train_config)
    if args.quick:  # as many updates as a CPU's quick run, whatever the batch
        scale = 1 if choice is None else max(1, choice.n_envs // CPU_N_ENVS)
        train_cfg = train_cfg.replace(
            total_env_steps=min(train_cfg.total_env_steps, scale * QUICK_TRAIN_STEPS)
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
    if choice is not None:
        print(choice.describe(), file=sys.stderr)
    if constant is None:
        say(f"no best constant setting for {cfg.name}: evaluated without it")
    result = main_job(
        cfg, out, seeds, penetrations, train_cfg, workers=args.workers,
        progress=not args.no_progress, say=say, device_choice=choice,
        constant=constant,
    )  # fmt: skip
    warn_outside_at_cap(result, "run")
    print(result["tables"])
    print(headline(result))
    if "conflict_summary" in result["training"]:
        print(f"training: {result['training']['conflict_summary']}")
    print(
        f"wrote {out / 'results.json'}, the tables and figures in {out}, the "
        f"training run in {out / TRAIN_DIR} ({result['wall_time_s']:.0f} s in all)"
    )


def cmd_train(args: argparse.Namespace) -> None:
    from agents.common.compilation import enable_compilation_cache
    from agents.common.config import (
        load_trainer_config,
        load_trainer_config_and_choice,
    )
    from agents.run import (
        ALGORITHMS,
        RUN_FILES,
        algorithm_of,
        clear_run,
        load_run_config,
        train_to_dir,
    )

    primary = join_processes(args)
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
        cfg, choice = load_trainer_config_and_choice(
            ALGORITHMS[algo].config, args.config
        )
        cfg = cfg.replace(**overrides) if overrides else cfg
        out = args.out
        if choice is not None:
            print(choice.describe(), file=sys.stderr)
        if primary:
            out = fresh_output_dir(args.out, args.force, RUN_FILES)
            clear_run(out)
            record = choice.as_comment() if choice is not None else ""
            (out / "config.yaml").write_text(record + cfg.to_yaml())
    if args.num_processes > 1:  # the others wait for the folder
        from jax.experimental.multihost_utils import sync_global_devices

        sync_global_devices("jaxround train: run folder ready")
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
    from agents.run.checkpoints import CheckpointMismatchError

    try:
        result = train_to_dir(
            cfg, out, resume=args.resume is not None, progress=not args.no_progress,
            say=say,
        )  # fmt: skip
    except CheckpointMismatchError as err:
        raise UsageError(f"--resume {out}: {err}") from None
    rate, last = result["env_steps_per_s"], result["last"]
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
    if result.get("conflict_summary"):
        print(result["conflict_summary"])
    print(f"wrote {out / 'metrics.csv'}, {out / 'learning_curves.png'}")
    if result["policy"]:
        print(f"policy: {result['policy']} (+ .json)")


def join_processes(args: argparse.Namespace) -> bool:
    """``--num-processes N``: join the other processes (`jax.distributed`),
    checked before any work. Returns whether this process writes the files."""
    if args.num_processes == 1:
        if args.process_id or args.coordinator:
            raise UsageError("--coordinator and --process-id need --num-processes > 1")
        return True
    if not args.coordinator:
        raise UsageError("--num-processes > 1 needs --coordinator HOST:PORT")
    from agents.run.distributed import initialize

    try:
        initialize(args.coordinator, args.num_processes, args.process_id)
    except ValueError as err:
        raise UsageError(str(err)) from None
    return args.process_id == 0


def cmd_export(args: argparse.Namespace) -> None:
    from agents.common.export import load_policy, policy_paths

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


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""
    p = sub.add_parser(
        "run", help="the main job: train, export, evaluate in JAX and SUMO, tables"
    )
    config_option(p)
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    p.add_argument("--seeds", type=positive_int, default=2, help="number of seeds")
    p.add_argument(
        "--quick", action="store_true",
        help=f"1 seed, 3 penetrations, {QUICK_TRAIN_STEPS:,} training steps "
        "(per 64 roundabouts of n_envs: auto)",
    )  # fmt: skip
    p.add_argument(
        "--train-config", default=None,
        help="PPO config YAML or built-in name, training on --config's roads "
        "(default: ppo_milan's recipe, on two-lane roads ppo_two_lane's, "
        "trained on --config)",
    )  # fmt: skip
    p.add_argument(
        "--total-steps", type=positive_int, default=None,
        help="training env steps (overrides the PPO config)",
    )  # fmt: skip
    best_constant_option(p)
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
    p.add_argument(
        "--num-processes", type=positive_int, default=1,
        help="train over this many processes (jax.distributed; n_envs is the "
        "batch of all of them)",
    )  # fmt: skip
    p.add_argument(
        "--process-id", type=non_negative_int, default=0,
        help="this process's number, 0 .. N-1 (process 0 writes the files)",
    )  # fmt: skip
    p.add_argument(
        "--coordinator", default=None, help="HOST:PORT where process 0 listens"
    )
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("export", help="copy a training run's policy (npz + json)")
    p.add_argument("run_dir", type=Path, help="a `jaxround train` folder")
    p.add_argument("--out", type=Path, required=True, help="policy.npz to write")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=cmd_export)
