"""The whole study in one call: train, export, evaluate in JAX and in SUMO.

`jaxround run` is `main_job`; `jaxround evaluate --sim sumo` is
`evaluate_everywhere`. Both write their files into one folder and return the
JSON they wrote (``results.json`` / ``evaluation.json``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from jaxround.analysis.front_plot import plot_main_front
from jaxround.analysis.report import percent_label, write_json, write_tables
from jaxround.analysis.results_tables import write_results_tables
from jaxround.scenario.best_constant import BestConstant
from jaxround.scenario.config import DRAIN_S, ScenarioConfig

#: Training folder inside the main job's output folder.
TRAIN_DIR = "train"
#: Env steps of the main job's training with --quick.
QUICK_TRAIN_STEPS = 262_144


def by_label(per_penetration: dict[float, Any]) -> dict[str, Any]:
    """``{0.1: x}`` -> ``{"10": x}``: penetrations as the paper's percent labels."""
    return {percent_label(p): m for p, m in per_penetration.items()}


#: What the policy does differently, drawn into the evaluation folder.
BEHAVIOUR_PNG = "behaviour.png"
#: Crossing time against CO2 of each driver, and the search's front.
FRONT_PNG = "front.png"
#: Penetrations at which the policy is compared with uncontrolled AVs.
COMPARED_PENETRATIONS = (0.5, 1.0)


def evaluate_everywhere(
    cfg: ScenarioConfig,
    policy: str | Path,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    out: Path,
    workers: int | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
    step: str = "",
    drain_s: float = DRAIN_S,
    constant: BestConstant | None = None,
) -> dict[str, Any]:
    """A policy over penetrations, beside uncontrolled AVs of the same vType
    and, when given, the best constant setting, in JAX and in SUMO, on the
    same schedules; tables, figures and JSON into `out`.

    Every mean is over the vehicles that arrived in every run of its
    schedule (all drivers, both simulators' own); Eq. 5 takes one min and
    max over every run of both simulators, so JAX's scores and SUMO's fall
    where their grams fall.

    Returns:
        ``{"scenario", "seeds", "policy", "sumo": {label: M},
        "sumo_uncontrolled": {label: M}, "jax": {label: M},
        "jax_uncontrolled": {label: M}, "max_vehicles": JAX's slots,
        "jax_slot_overflow": vehicle-steps, "cap_s": the longest a JAX run
        went on, "jax_not_arrived" and "sumo_not_arrived": vehicles not out
        by then, "outside_at_cap": `outside_at_cap`, "comparison":
        {...}, "tables"}`` with
        M as `jaxround.analysis.metrics.class_metrics` (means over seeds) plus the
        safety counters, and "comparison" as `compare_with_uncontrolled`;
        with a `constant` also "best_constant" (its file's content),
        "sumo_best_constant", "jax_best_constant" and
        "comparison_best_constant" (`compare_best_constant`). Also written
        to ``out/evaluation.json``.
    """
    from agents.common.evaluation import run_drivers, summarise_drivers
    from jaxround.analysis.metrics import sweep_scale
    from jaxround.envs.constant_setting import constant_config
    from sumo_export.evaluate import compare_drivers, policy_controller, sumo_runs
    from sumo_export.policy_report import write_policy_report
    from sumo_export.scripted import ScriptedControllerFactory

    n = f"{len(penetrations)} penetrations x {len(seeds)} seed(s)"
    factory = policy_controller(cfg, policy)  # a bad policy fails before any run
    others = "uncontrolled AVs" + (", best constant" if constant else "")
    say(f"{step}JAX: policy, {others}, {n}")
    jax_runs = run_drivers(
        policy, cfg, penetrations, seeds, drain_s=drain_s, constant=constant,
        progress=progress,
    )  # fmt: skip
    say(f"{step}SUMO: the policy through libsumo, then {others}, {n}")
    runs = {
        "policy": sumo_runs(cfg, penetrations, seeds, workers, progress, factory,
                            desc="SUMO, policy", drain_s=drain_s),
        "uncontrolled": sumo_runs(cfg, penetrations, seeds, workers, progress,
                                  desc="SUMO, uncontrolled AVs", drain_s=drain_s),
    }  # fmt: skip
    if constant is not None:
        spec = constant.controller_spec
        runs["best_constant"] = sumo_runs(
            constant_config(cfg, constant), penetrations, seeds, workers, progress,
            None if spec is None else ScriptedControllerFactory(spec),
            desc="SUMO, best constant", drain_s=drain_s,
        )  # fmt: skip
    sumo_records = {
        d: {p: [r.records for r in rs] for p, rs in by_p.items()}
        for d, by_p in runs.items()
    }
    # Eq. 5 on one scale over every run of both simulators
    every = [
        r
        for by_driver in (jax_runs.records, sumo_records)
        for by_p in by_driver.values()
        for rs in by_p.values()
        for r in rs
    ]
    scale = sweep_scale(every, over="joint")
    jax_eval = summarise_drivers(jax_runs, scale)
    jax_results = jax_eval["results"]
    # the same vehicles on both sides
    summaries = compare_drivers(cfg, runs, score_scale=scale)
    means = {
        d: {p: r["mean"] for p, r in by_p.items()} for d, by_p in summaries.items()
    }
    for driver, by_p in jax_results.items():  # policy, uncontrolled, best_constant
        write_tables(by_p, out, f"jax_{driver}", "joint")
        if driver != "policy":  # the policy's in SUMO: write_policy_report's
            write_tables(means[driver], out, f"sumo_{driver}")
    tables = write_policy_report(
        cfg, summaries["policy"], out, policy, jax_results=jax_results["policy"]
    )
    result = {
        "scenario": cfg.name,
        "seeds": list(seeds),
        "policy": str(policy),
        "sumo": by_label(means["policy"]),
        "sumo_uncontrolled": by_label(means["uncontrolled"]),
        "jax": by_label(jax_results["policy"]),
        "jax_uncontrolled": by_label(jax_results["uncontrolled"]),
        "max_vehicles": jax_eval["max_vehicles"],
        "jax_slot_overflow": jax_eval["jax_slot_overflow"],
        "cap_s": jax_eval["cap_s"],
        "jax_not_arrived": jax_eval["jax_not_arrived"],
        "sumo_not_arrived": sum(
            int((~r.arrived).sum())
            for by_p in sumo_records.values()
            for rs in by_p.values()
            for r in rs
        ),
        "outside_at_cap": outside_at_cap(jax_eval, sumo_records, seeds),
        "score_scale": "joint",
        "comparison": compare_with_uncontrolled(
            {"sumo": sumo_records, "jax": jax_runs.records}
        ),
        "tables": tables,
    }
    if constant is not None:
        result["best_constant"] = {**constant.to_dict(), "source": constant.source}
        result["sumo_best_constant"] = by_label(means["best_constant"])
        result["jax_best_constant"] = by_label(jax_results["best_constant"])
        result["comparison_best_constant"] = compare_best_constant(
            {"sumo": sumo_records, "jax": jax_runs.records}
        )
    write_results_tables(result, out)
    plot_main_front(result, out / FRONT_PNG)
    from agents.common.behaviour import plot_behaviour, policy_behaviour

    behaviour = policy_behaviour(policy, cfg, penetration=1.0, seed=seeds[0])
    plot_behaviour(
        behaviour, out / BEHAVIOUR_PNG,
        f"{cfg.name}, 100% AVs, seed {seeds[0]}: the policy's AVs and uncontrolled AVs",
    )  # fmt: skip
    write_json(result, out / "evaluation.json")
    return result


def outside_at_cap(
    jax_eval: dict[str, Any],
    sumo_records: dict[str, dict[float, list[Any]]],
    seeds: Sequence[int],
) -> list[dict[str, Any]]:
    """The runs that left vehicles outside at the cap, JAX's then SUMO's:
    ``[{"sim", "driver", "penetration", "seed", "not_arrived"}]``."""
    out = [{"sim": "jax", **entry} for entry in jax_eval["outside_at_cap"]]
    for driver, by_p in sumo_records.items():
        for p, rs in by_p.items():
            for seed, r in zip(seeds, rs, strict=True):
                left = int((~r.arrived).sum())
                if left:
                    out.append({"sim": "sumo", "driver": driver, "penetration": p,
                                "seed": seed, "not_arrived": left})  # fmt: skip
    return out


def paired_drivers(
    records: dict[str, dict[str, dict[float, list[Any]]]],
    driver: str,
    baseline: str,
) -> dict[str, Any]:
    """`driver` minus `baseline`, paired on the same schedules, at
    `COMPARED_PENETRATIONS`.

    Args:
        records: ``{sim: {driver: {penetration: [records per seed]}}}``.

    Returns:
        ``{sim: {label: {"all" | "hv" | "av": compare.paired_difference}},
        "sumo_to_jax_gain": {label: ratio}}``; the ratio is the SUMO
        difference in mean crossing time of all vehicles over the JAX one
        (None where JAX shows none).
    """
    from jaxround.analysis.compare import paired_difference

    out: dict[str, Any] = {}
    for sim, by_driver in records.items():
        out[sim] = {}
        for p in COMPARED_PENETRATIONS:
            if p not in by_driver[driver]:
                continue
            pol, base = by_driver[driver][p], by_driver[baseline][p]
            out[sim][percent_label(p)] = {
                c: paired_difference(pol, base, c) for c in ("all", "hv", "av")
            }
    ratios = {}
    for label, by_class in out.get("sumo", {}).items():
        sumo_t = by_class["all"]["crossing_time_s"]
        jax_t = out.get("jax", {}).get(label, {}).get("all", {}).get("crossing_time_s")
        ok = sumo_t and jax_t and abs(jax_t["diff"]) > 1e-9
        ratios[label] = sumo_t["diff"] / jax_t["diff"] if ok else None
    out["sumo_to_jax_gain"] = ratios
    return out


def compare_with_uncontrolled(
    records: dict[str, dict[str, dict[float, list[Any]]]],
) -> dict[str, Any]:
    """Policy against uncontrolled AVs (`paired_drivers`)."""
    return paired_drivers(records, "policy", "uncontrolled")


def compare_best_constant(
    records: dict[str, dict[str, dict[float, list[Any]]]],
) -> dict[str, Any]:
    """``{"policy_vs_best_constant": ..., "best_constant_vs_uncontrolled":
    ...}``, each as `paired_drivers`."""
    return {
        "policy_vs_best_constant": paired_drivers(records, "policy", "best_constant"),
        "best_constant_vs_uncontrolled": paired_drivers(
            records, "best_constant", "uncontrolled"
        ),
    }


def main_job(
    cfg: ScenarioConfig,
    out: Path,
    seeds: Sequence[int],
    penetrations: Sequence[float],
    train_config: Any,
    workers: int | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
    device_choice: Any = None,
    constant: BestConstant | None = None,
) -> dict[str, Any]:
    """Scenario files, PPO training, export, evaluation in JAX and SUMO.

    Args:
        cfg: the scenario evaluated (full demand).
        out: a fresh output folder.
        seeds: schedule seeds of the evaluation.
        penetrations: AV shares of the evaluation.
        train_config: the `agents.common.config.PPOConfig` to train.
        device_choice: what ``n_envs: auto`` chose for it
            (`agents.common.device_batch.DeviceChoice`), kept in the results.
        constant: the best constant setting evaluated beside the policy
            (`jaxround.scenario.best_constant`); None: none.

    Returns:
        The ``results.json`` object: ``{"sumo": {label: M}, "jax": {label:
        M}, ...}`` (`evaluate_everywhere`) plus the training summary; its
        "policy" is the policy's file relative to `out`.
    """
    from agents.common.compilation import enable_compilation_cache
    from agents.run import clear_run, train_to_dir
    from jaxround.scenario.schedule import make_schedule
    from sumo_export.scenario import write_scenario

    started = time.time()
    write_scenario(cfg, make_schedule(cfg), out / "scenario")
    say(f"[1/4] scenario files in {out / 'scenario'}")
    train_dir = out / TRAIN_DIR
    train_dir.mkdir(parents=True, exist_ok=True)
    clear_run(train_dir)
    record = device_choice.as_comment() if device_choice is not None else ""
    (train_dir / "config.yaml").write_text(record + train_config.to_yaml())
    say(
        f"[2/4] PPO on {train_config.scenario}: {train_config.num_updates} updates "
        f"of {train_config.n_envs} x {train_config.n_steps} env steps into "
        f"{train_dir}"
    )
    enable_compilation_cache()
    trained = train_to_dir(train_config, train_dir, progress=progress, say=say)
    policy = Path(trained["policy"])
    result = evaluate_everywhere(
        cfg, policy, penetrations, seeds, out, workers, progress, say, "[3-4/4] ",
        constant=constant,
    )  # fmt: skip
    result["training"] = {
        "updates": trained["updates"],
        "env_steps": trained["updates"] * train_config.env_steps_per_update,
        "env_steps_per_s": trained["env_steps_per_s"],
        "last": trained["last"],
        "n_envs": train_config.n_envs,
        "n_steps": train_config.n_steps,
        "device_batch": None if device_choice is None else device_choice.to_dict(),
    }
    if "conflict_summary" in trained:  # constrained PPO: its limits and prices
        for key in ("conflict_limit_per_1000", "conflict_price", "conflict_summary"):
            result["training"][key] = trained[key]
    result["wall_time_s"] = round(time.time() - started, 1)
    # the run's own files by their place in it, as the results travel with it
    result["policy"] = os.path.relpath(policy, out)
    write_json(result, out / "results.json")
    return result


def headline(result: dict[str, Any]) -> str:
    """Crossing times at 0%, 50% and 100% AVs in both simulators; the policy
    against uncontrolled AVs, and with a best constant, the policy against it
    and it against uncontrolled AVs, in words."""
    lines = []
    for sim in ("sumo", "sumo_best_constant", "sumo_uncontrolled", "jax",
                "jax_best_constant", "jax_uncontrolled"):  # fmt: skip
        runs = result.get(sim, {})
        parts = []
        for label, cls in (("0", "hv"), ("50", "hv"), ("50", "av"), ("100", "av")):
            m = runs.get(label, {}).get(cls, {})
            t = m.get("mean_crossing_time_s")
            if t is not None:
                parts.append(f"{cls.upper()}s at {label}%: {t:.2f} s")
        if parts:
            lines.append(f"{sim}: " + ", ".join(parts))
    pairs = {"policy minus uncontrolled": result.get("comparison", {})}
    for key, pair in result.get("comparison_best_constant", {}).items():
        pairs[key.replace("_vs_", " minus ").replace("_", " ")] = pair
    for what, comparison in pairs.items():
        for sim, by_label in comparison.items():
            if sim == "sumo_to_jax_gain":
                continue
            for label, by_class in by_label.items():
                t, c = by_class["all"]["crossing_time_s"], by_class["all"]["co2_g"]
                if t is None or c is None:
                    continue
                k = by_class["all"].get("conflicts_per_1000_veh")
                conflicts = "" if k is None else (
                    f", conflicts per 1,000 veh {k['policy']:.1f} against "
                    f"{k['baseline']:.1f}"
                )  # fmt: skip
                lines.append(
                    f"{sim}, {label}% AVs, {what}: crossing time "
                    f"{t['diff']:+.2f} s ({100 * t['rel_diff']:+.1f}%), CO2 "
                    f"{c['diff']:+.2f} g/veh ({100 * c['rel_diff']:+.1f}%)" + conflicts
                )
    return "\n".join(lines)
