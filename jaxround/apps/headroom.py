"""Headroom before training: what AVs could gain over their own vType.

    python -m jaxround.apps.headroom --out runs/headroom

On the same departure schedules (evaluation seeds, never training seeds) at
100% and 50% AVs, runs in SUMO and in JAX

- the AV vType itself (the baseline), uncontrolled;
- uncontrolled AV vTypes with one driver number changed (accel, tau, gap
  acceptance: jmTimegapMinor and impatience, and the desired-speed factor),
  and one assertive envelope: what per-vehicle parameter actions or a new
  vType could reach;
- scripted controllers (`jaxround.envs.scripted`) commanding the AV vType's
  speed: what speed commands under the IDM can reach.

Each variant is compared with the baseline on the same vehicles
(`jaxround.analysis.compare.paired_difference`): the paired difference of mean
crossing time (all vehicles) and CO2 per vehicle, with 95% t-intervals over
the seeds and over vehicles (vehicles of one run are not independent, so the
second is narrower than the truth). Both simulators run until every vehicle
has left. Writes ``headroom.json`` and ``headroom.png`` into the output
folder and prints the table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxround.analysis.compare import paired_difference
from jaxround.analysis.headroom_plot import plot, table
from jaxround.analysis.metrics import class_metrics
from jaxround.apps.cli.arguments import workers_option
from jaxround.envs.observe import rich_observation
from jaxround.envs.rollout import run_until_left, vehicle_records
from jaxround.envs.roundabout import make
from jaxround.envs.scripted import NO_COMMAND, RULES, rule_and_value, scripted_command
from jaxround.envs.supported import check_single_lane
from jaxround.scenario.config import ScenarioConfig, load_config
from jaxround.scenario.records import VehicleRecords
from jaxround.scenario.schedule import Schedule, make_schedule

#: Evaluation seeds: training uses seeds below 100.
EVAL_SEEDS = (100, 101, 102)
PENETRATIONS = (1.0, 0.5)
#: AV driver numbers swept one at a time around the Milan AV vType
#: (accel 2.6, tau 1, jmTimegapMinor 1, impatience 0, speedFactor 1).
SWEEP: dict[str, tuple[float, ...]] = {
    "accel": (2.0, 3.5, 5.0),
    "tau": (0.5, 0.75, 1.5),
    "jm_timegap_minor": (0.5, 2.0),
    "impatience": (0.25, 0.5, 1.0),
    "speed_factor": (0.9, 1.1, 1.2),
}
#: An assertive envelope vType, under which a policy could command speeds.
ENVELOPE = (("accel", 3.5), ("tau", 0.6), ("impatience", 0.5))
#: Scripted controllers on the AV vType; accel:1000 commands the IDM speed.
SCRIPTED = (
    "accel:1000",
    "cruise:8",
    "cruise:10",
    "eco:0.3",
    "eco:1",
    "timed:2",
    "timed:5",
)
#: Scripted controllers on the envelope vType.
ON_ENVELOPE = ("cruise:8", "cruise:10")
#: JAX episodes per compiled batch.
JAX_BATCH = 12
#: The rule and value that give no command (`scripted.constant_accel` of
#: NaN): uncontrolled AVs in the same compiled program as the scripts.
UNCONTROLLED = (list(RULES).index("accel"), NO_COMMAND)


@dataclass(frozen=True)
class Variant:
    """One row of the study.

    Attributes:
        label: e.g. ``"vtype"``, ``"tau=0.5"``, ``"eco:0.3"``.
        av: AV driver numbers changed from the config (``speed_factor``: the
            AVs' desired-speed factor).
        controller: a scripted controller spec, None for uncontrolled AVs.
    """

    label: str
    av: tuple[tuple[str, float], ...] = ()
    controller: str | None = None


def variants() -> list[Variant]:
    """The baseline first, then the vType sweep, the envelope, the scripts on
    the AV vType and on the envelope."""
    out = [Variant("vtype")]
    for field, values in SWEEP.items():
        out += [Variant(f"{field}={v:g}", ((field, v),)) for v in values]
    out.append(Variant("envelope", ENVELOPE))
    out += [Variant(spec, controller=spec) for spec in SCRIPTED]
    out += [Variant(f"envelope+{spec}", ENVELOPE, spec) for spec in ON_ENVELOPE]
    return out


def variant_config(cfg: ScenarioConfig, variant: Variant) -> ScenarioConfig:
    """The scenario with the variant's AV vType, validated. A speed factor
    is carried by the schedule: the AVs' speedDev is set to the human
    drivers' so that `variant_schedule`'s factors reach both simulators."""
    av = dict(variant.av)
    if "speed_factor" in av:
        av.pop("speed_factor")
        av["speed_dev"] = cfg.drivers.hv.speed_dev
    driver = dataclasses.replace(cfg.drivers.av, **av)
    new = dataclasses.replace(cfg, drivers=dataclasses.replace(cfg.drivers, av=driver))
    new.validate()
    return new


def variant_schedule(schedule: Schedule, variant: Variant) -> Schedule:
    """The schedule with the AVs' desired-speed factor of the variant."""
    factor = dict(variant.av).get("speed_factor")
    if factor is None:
        return schedule
    return dataclasses.replace(
        schedule,
        speed_factor=np.where(schedule.is_av, factor, schedule.speed_factor),
    )


def schedules(
    cfg: ScenarioConfig, seeds: Sequence[int], variant: Variant
) -> list[Schedule]:
    """The variant's schedules, penetration-major: (p, seed) for p, seed."""
    return [
        variant_schedule(make_schedule(cfg, seed=s, penetration=p), variant)
        for p in PENETRATIONS
        for s in seeds
    ]


# ------------------------------------------------------------------ simulators


def run_sumo(
    cfg: ScenarioConfig,
    rows: Sequence[Variant],
    seeds: Sequence[int],
    workers: int | None = None,
) -> dict[str, list[Any]]:
    """Every variant's runs in SUMO: label -> `SumoRun` per `schedules` entry."""
    from sumo_export.runner import run_many
    from sumo_export.scripted import ScriptedControllerFactory

    total = len(rows) * len(seeds) * len(PENETRATIONS)
    out = {}
    with tqdm(total=total, desc="SUMO runs", unit="run") as bar:
        for variant in rows:
            factory = (
                ScriptedControllerFactory(variant.controller)
                if variant.controller
                else None
            )
            out[variant.label] = run_many(
                variant_config(cfg, variant),
                schedules(cfg, seeds, variant),
                workers=workers,
                progress=lambda _run: bar.update(),
                controller=factory,
            )
    return out


def run_jax(
    cfg: ScenarioConfig, rows: Sequence[Variant], seeds: Sequence[int]
) -> dict[str, list[dict[str, Any]]]:
    """Every variant's episodes in JAX, batches of `JAX_BATCH` in one compiled
    program (vType numbers, schedules and the scripted rule are traced):
    label -> ``{"records", "overflow", "max_vehicles"}`` per `schedules` entry."""
    from jaxround.scenario.config import DRAIN_S

    # the scripts command speeds, whatever action the scenario's agent has
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, action="accel"))
    # as long as SUMO may run; each episode stops when its vehicles have left
    env, base = make(cfg, episode_s=cfg.demand.duration_s + DRAIN_S)
    jobs = []  # (label, params, schedule, rule, value)
    for variant in rows:
        av = dict(variant.av)
        own = {k: jnp.float32(v) for k, v in av.items() if k != "speed_factor"}
        params = base.replace(av=base.av.replace(**own))
        rule, value = (
            rule_and_value(variant.controller) if variant.controller else UNCONTROLLED
        )
        factor = av.get("speed_factor")
        for sched in schedules(cfg, seeds, variant):
            js = env.schedule_from_numpy(sched)
            if factor is not None:  # the base config's AVs drive at factor 1
                js = js.replace(
                    speed_factor=jnp.where(js.is_av, factor, js.speed_factor)
                )
            jobs.append((variant.label, params, js, rule, value))

    def episode(params, schedule, rule, value):
        def policy(obs, state, key):
            del obs, key
            rich = rich_observation(env.net, state, params, env.route_destination)
            accel = scripted_command(rich, rule, value, env.dt)
            return jnp.stack([accel, jnp.full_like(accel, jnp.nan)], axis=1)

        return run_until_left(env, params, schedule, jax.random.PRNGKey(0), policy)

    batched = jax.jit(jax.vmap(episode))
    out: dict[str, list[dict[str, Any]]] = {}
    for start in tqdm(range(0, len(jobs), JAX_BATCH), desc="JAX batches"):
        chunk = jobs[start : start + JAX_BATCH]
        padded = chunk + [chunk[-1]] * (JAX_BATCH - len(chunk))  # one shape
        states = batched(
            _stack([j[1] for j in padded]),
            _stack([j[2] for j in padded]),
            jnp.asarray([j[3] for j in padded]),
            jnp.asarray([j[4] for j in padded], jnp.float32),
        )
        for i, job in enumerate(chunk):
            state = jax.tree.map(lambda x, i=i: x[i], states)
            out.setdefault(job[0], []).append(
                {
                    "records": vehicle_records(env, state),
                    "overflow": int(state.stats.overflow),
                    "max_vehicles": env.max_vehicles,
                }
            )
    return out


def _arrived(records: VehicleRecords, horizon_s: float) -> int:
    return class_metrics(records, horizon_s)["all"]["n_arrived"]


def _stack(trees: list[Any]) -> Any:
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *trees)


# ------------------------------------------------------------------ statistics


def summarise(
    cfg: ScenarioConfig,
    rows: Sequence[Variant],
    seeds: Sequence[int],
    sumo: dict[str, list[Any]],
    jax_runs: dict[str, list[dict[str, Any]]],
) -> list[dict[str, Any]]:
    """One entry per variant and penetration: SUMO and JAX paired differences
    (all vehicles; human drivers too at a mixed penetration), safety counters."""
    horizon = cfg.demand.duration_s
    k = len(seeds)
    out = []
    for variant in rows:
        for j, p in enumerate(PENETRATIONS):
            part = slice(j * k, (j + 1) * k)
            s_base = [r.records for r in sumo["vtype"][part]]
            s_runs = sumo[variant.label][part]
            j_base = [r["records"] for r in jax_runs["vtype"][part]]
            j_runs = jax_runs[variant.label][part]
            s_rec = [r.records for r in s_runs]
            j_rec = [r["records"] for r in j_runs]
            entry = {
                "variant": variant.label,
                "av": dict(variant.av),
                "controller": variant.controller,
                "penetration": p,
                "sumo": paired_difference(s_rec, s_base),
                "jax": paired_difference(j_rec, j_base),
                "sumo_arrived": [_arrived(r, horizon) for r in s_rec],
                "jax_arrived": [_arrived(r, horizon) for r in j_rec],
                "sumo_collisions": sum(r.collisions for r in s_runs),
                "sumo_emergency_brakings": sum(r.emergency_brakings for r in s_runs),
                "sumo_teleports": sum(r.teleports for r in s_runs),
                "jax_slot_overflow": int(sum(r["overflow"] for r in j_runs)),
            }  # fmt: skip
            if 0.0 < p < 1.0:
                entry["sumo_hv"] = paired_difference(s_rec, s_base, "hv")
                entry["jax_hv"] = paired_difference(j_rec, j_base, "hv")
            out.append(entry)
    return out


def base_values(cfg: ScenarioConfig) -> dict[str, float]:
    """The AV vType's own value of each swept field."""
    av = cfg.drivers.av
    return {f: 1.0 if f == "speed_factor" else getattr(av, f) for f in SWEEP}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxround.apps.headroom")
    parser.add_argument("--out", required=True, help="folder for the results")
    parser.add_argument("--config", default="milan", help="scenario (default milan)")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(EVAL_SEEDS))
    workers_option(parser)
    args = parser.parse_args(argv)
    if args.executor != "local":
        from sumo_export.executors import use_executor

        use_executor(args.executor)
    if min(args.seeds) < 100:
        parser.error("--seeds: evaluation seeds must be >= 100 (training uses 0-99)")
    out = Path(args.out)
    if (out / "headroom.json").exists():
        parser.error(f"--out: {out / 'headroom.json'} exists; choose another folder")
    cfg = load_config(args.config)
    check_single_lane(cfg, "headroom")  # before SUMO runs: AV settings
    rows = variants()
    sumo = run_sumo(cfg, rows, args.seeds, args.workers)
    jax_runs = run_jax(cfg, rows, args.seeds)
    entries = summarise(cfg, rows, args.seeds, sumo, jax_runs)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "scenario": cfg.name, "seeds": args.seeds, "rules": list(RULES),
        "max_vehicles": next(iter(jax_runs.values()))[0]["max_vehicles"],
        "jax_slot_overflow": sum(e["jax_slot_overflow"] for e in entries),
    }  # fmt: skip
    (out / "headroom.json").write_text(json.dumps({**meta, "rows": entries}, indent=1))
    plot(entries, SWEEP, base_values(cfg), out / "headroom.png")
    print(table(entries))
    return 0


if __name__ == "__main__":
    sys.exit(main())
