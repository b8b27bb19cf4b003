"""Commands of the calibration: `measure` (a survey of SUMO runs) and `calibrate`."""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxround.apps.cli.arguments import (
    UsageError,
    config_option,
    fresh_output_dir,
    positive_int,
    seeds_of,
    warn_slot_overflow,
    workers_option,
)
from jaxround.scenario.config import load_config


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
    from jaxround.analysis.survey import SLOT_S, n_slots_for
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
    from jaxround.analysis.calibrate import parse_param_names
    from jaxround.analysis.survey import load_survey
    from jaxround.apps.calibration_job import run_calibration

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


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""
    p = sub.add_parser(
        "measure",
        help="survey SUMO runs per leg and 10-minute slot (targets for calibrate)",
    )
    config_option(p)
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
    config_option(p)
    p.add_argument("--targets", type=Path, required=True, help="from jaxround measure")
    p.add_argument(
        "--params", default="accel,tau,jm_timegap_minor",
        help="human-driver numbers to fit, comma-separated, among accel, decel, "
        "tau, min_gap, delta, jm_timegap_minor, impatience (default "
        "accel,tau,jm_timegap_minor)",
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
