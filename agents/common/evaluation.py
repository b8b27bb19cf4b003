"""An exported policy on the full scenario in JAX, across penetrations and seeds.

    summary = evaluate_policy("runs/ppo", load_config("milan"), [0, 0.5, 1], [0, 1])

Every (penetration, seed) runs the very schedule SUMO runs
(`jaxround.scenario.schedule.make_schedule`: one seed's AVs at 10% are a subset of its
AVs at 20%), twice: AVs driven by the policy, and AVs uncontrolled (their
IDM vType, the environment's default) as the baseline. All runs go in one
vmapped, jitted batch; a per-run flag picks the driver.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.common.export import (
    PolicyLayout,
    check_scenario,
    load_policy,
    policy_action,
)
from agents.common.networks import lane_column
from jaxround.analysis.metrics import (
    SCORE_SCALES,
    ScoreScale,
    arrived_in_all,
    class_metrics,
    mean_over_runs,
    sweep_scale,
)
from jaxround.core.capacity import road_capacity
from jaxround.core.state import EnvState
from jaxround.envs.constant_setting import constant_setting_runs
from jaxround.envs.rollout import (
    NO_COMMAND,
    Policy,
    runs_until_left,
    vehicle_records,
)
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.envs.slots import redo_on_overflow
from jaxround.scenario.best_constant import BestConstant
from jaxround.scenario.config import DRAIN_S, ScenarioConfig, config_from_dict
from jaxround.scenario.schedule import make_schedule

#: The two drivers of the AVs, in the order of the results.
DRIVERS = ("policy", "uncontrolled")


def with_observer(
    cfg: ScenarioConfig, observer: str, action: str | None = None
) -> ScenarioConfig:
    """`cfg` with the AVs' observer (and action) the policy was trained with."""
    action = cfg.agent.action if action is None else action
    if cfg.agent.observer == observer and cfg.agent.action == action:
        return cfg
    d = cfg.to_dict()
    d["agent"]["observer"] = observer
    d["agent"]["action"] = action
    return config_from_dict(d)


def switched_policy(
    arrays: dict[str, jax.Array], layout: PolicyLayout, use_policy: jax.Array
) -> Policy:
    """The exported policy's deterministic action, or no command (uncontrolled:
    the AVs drive their vType) where `use_policy` is false. A
    `jaxround.envs.rollout.Policy`."""

    def act(obs: jax.Array, state: EnvState, key: jax.Array) -> jax.Array:
        del key
        accel, change = policy_action(arrays, layout, obs, state.active, jnp)
        accel = jnp.where(use_policy, accel, NO_COMMAND)
        change = jnp.where(use_policy, change, 0)
        return jnp.stack([accel, lane_column(change)], axis=-1).astype(jnp.float32)

    return act


@dataclass
class DriverRuns:
    """Every run of `run_drivers`, before any metric.

    Attributes:
        records: ``{driver: {penetration: [VehicleRecords per seed]}}``.
        stats: the same of each run's final `EpisodeStats`.
        max_vehicles: slots M of the reported policy runs; tried: every M.
    """

    cfg: ScenarioConfig
    policy: str
    layout: PolicyLayout
    penetrations: list[float]
    seeds: list[int]
    cap_s: float
    max_vehicles: int
    tried: list[int]
    records: dict[str, dict[float, list[Any]]]
    stats: dict[str, dict[float, list[Any]]]


def run_drivers(
    policy_path: str | Path,
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    max_vehicles: int | str | None = None,
    drain_s: float = DRAIN_S,
    constant: BestConstant | None = None,
    progress: bool = False,
) -> DriverRuns:
    """The policy and the uncontrolled baseline on every schedule in one
    batch, and the constant setting (driver "best_constant") on the same
    schedules in another (`jaxround.envs.constant_setting`) when given.
    Arguments as `evaluate_policy`'s; ``progress``: progress bars in
    simulated time on stderr."""
    arrays, layout = load_policy(policy_path)
    check_scenario(layout, cfg)
    cfg = with_observer(cfg, layout.observer, layout.action)
    # every run goes on until its vehicles have left, as SUMO's runs do, or
    # to the same cap (the demand horizon plus drain_s)
    cap_s = cfg.demand.duration_s + drain_s
    env, params = make(cfg, max_vehicles=max_vehicles, episode_s=cap_s)
    obs, _ = jax.eval_shape(env.reset, jax.random.PRNGKey(0), params)
    if obs.shape[-1] != layout.obs_size:
        raise ValueError(
            f"the policy reads {layout.obs_size} numbers per vehicle "
            f"({layout.observer!r} observer), the environment gives {obs.shape[-1]}"
        )
    runs = [(d, p, s) for d in DRIVERS for p in penetrations for s in seeds]
    numpy_schedules = {
        (p, s): make_schedule(cfg, seed=s, penetration=p)
        for p in penetrations
        for s in seeds
    }
    use_policy = np.array([d == "policy" for d, _, _ in runs])
    keys = jax.random.split(jax.random.PRNGKey(0), len(runs))
    weights = {k: jnp.asarray(v) for k, v in arrays.items()}

    def run_with(slots: int) -> tuple[RoundaboutEnv, EnvState]:
        """Every run with `slots` vehicle slots, side by side."""
        env, params = make(cfg, max_vehicles=slots, episode_s=cap_s)
        batch = jax.tree.map(
            lambda *xs: np.stack(xs),
            *[env.schedule_from_numpy(numpy_schedules[(p, s)]) for _, p, s in runs],
        )

        return env, runs_until_left(
            env, params, batch, keys,
            lambda flag: switched_policy(weights, layout, flag),
            jnp.asarray(use_policy),
            desc=f"JAX, {len(runs)} runs side by side" if progress else None,
        )  # fmt: skip

    (env, states), tried = redo_on_overflow(
        run_with, lambda run: int(np.sum(run[1].stats.overflow)),
        max_vehicles=env.max_vehicles, road=road_capacity(env.network, cfg),
        what="evaluate (JAX)",
    )  # fmt: skip
    batches = [(env, states, runs)]
    if constant is not None:
        jobs = [("best_constant", p, s) for p in penetrations for s in seeds]
        env_c, states_c, _ = constant_setting_runs(
            cfg, constant, [numpy_schedules[(p, s)] for _, p, s in jobs],
            max_vehicles=env.max_vehicles, cap_s=cap_s, progress=progress,
        )  # fmt: skip
        batches.append((env_c, states_c, jobs))
    records: dict[str, dict[float, list[Any]]] = {}
    stats: dict[str, dict[float, list[Any]]] = {}
    for batch_env, batch_states, batch_runs in batches:
        for i, (driver, p, _) in enumerate(batch_runs):
            state = jax.tree.map(lambda x, i=i: x[i], batch_states)
            rec = vehicle_records(batch_env, state)
            records.setdefault(driver, {}).setdefault(p, []).append(rec)
            stats.setdefault(driver, {}).setdefault(p, []).append(state.stats)
    return DriverRuns(
        cfg=cfg, policy=str(policy_path), layout=layout,
        penetrations=list(penetrations), seeds=list(seeds), cap_s=cap_s,
        max_vehicles=env.max_vehicles, tried=tried, records=records, stats=stats,
    )  # fmt: skip


def summarise_drivers(
    runs: DriverRuns, score_scale: str | ScoreScale = "sweep"
) -> dict[str, Any]:
    """The metrics of every driver, over the same vehicles: each schedule's
    means are over the vehicles that arrived in every driver's run of it.

    Args:
        score_scale: Eq. 5's min and max over every run here ("sweep"), each
            run's own ("run"), or the bounds themselves (`ScoreScale`, e.g.
            over JAX's and SUMO's runs together).

    Returns:
        `evaluate_policy`'s result, without "records".
    """
    if not isinstance(score_scale, ScoreScale) and score_scale not in SCORE_SCALES:
        raise ValueError(f"score_scale {score_scale!r}, expected one of {SCORE_SCALES}")
    records, drivers = runs.records, list(runs.records)
    compared = {
        (p, k): arrived_in_all(records[d][p][k] for d in drivers)
        for p in runs.penetrations
        for k in range(len(runs.seeds))
    }
    every = [r for by_p in records.values() for rs in by_p.values() for r in rs]
    if isinstance(score_scale, ScoreScale):
        scale: ScoreScale | None = score_scale
    else:
        scale = sweep_scale(every) if score_scale == "sweep" else None
    per_run: dict[tuple[str, float], list[dict[str, Any]]] = {}
    overflow = not_arrived = 0
    outside: list[dict[str, Any]] = []
    horizon = runs.cfg.demand.duration_s
    for driver in drivers:
        for p in runs.penetrations:
            for k, seed in enumerate(runs.seeds):
                final = runs.stats[driver][p][k]
                m = class_metrics(
                    records[driver][p][k], horizon, compared=compared[(p, k)],
                    scale=scale,
                )  # fmt: skip
                m["collisions"] = int(final.collisions)
                m["slot_overflow"] = int(final.overflow)
                overflow += m["slot_overflow"]
                left = m["all"]["n_not_arrived"]
                not_arrived += left
                if left:
                    outside.append({"driver": driver, "penetration": p,
                                    "seed": seed, "not_arrived": left})  # fmt: skip
                per_run.setdefault((driver, p), []).append(m)
    layout = runs.layout
    return {
        "scenario": runs.cfg.name,
        "seeds": runs.seeds,
        "policy": runs.policy,
        "layout": {
            "observer": layout.observer,
            "obs_size": layout.obs_size,
            "hidden": list(layout.hidden),
            "centralised": layout.centralised,
        },
        "max_vehicles": runs.max_vehicles,
        "max_vehicles_tried": runs.tried,
        "jax_slot_overflow": overflow,
        "cap_s": runs.cap_s,
        "jax_not_arrived": not_arrived,
        "outside_at_cap": outside,
        "score_scale": "run" if scale is None else scale.over,
        "results": {
            d: {p: mean_over_runs(per_run[(d, p)]) for p in runs.penetrations}
            for d in drivers
        },
    }


def evaluate_policy(
    policy_path: str | Path,
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    max_vehicles: int | str | None = None,
    keep_records: bool = False,
    drain_s: float = DRAIN_S,
    score_scale: str = "sweep",
    constant: BestConstant | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Run the policy and the uncontrolled baseline on every schedule.

    The two are compared over the same vehicles: each schedule's means are
    over the vehicles that arrived in both runs of it (the others counted
    per run: ``n_not_arrived``, "outside_at_cap").

    Args:
        policy_path: the exported policy (``.npz``, ``.json``, stem or folder).
        cfg: the scenario (full demand); its observer is set to the policy's.
        penetrations: AV shares.
        seeds: schedule seeds.
        max_vehicles: vehicle slots M; None: the config's, else what the
            traffic needs (`jaxround.envs.slots`); runs whose slots overflow
            are redone with more (`redo_on_overflow`).
        keep_records: also return each run's `VehicleRecords` under
            ``"records": {driver: {penetration: [per seed]}}`` (not JSON).
        drain_s: simulated seconds after the demand horizon a run may go on
            for its last vehicles (the cap is the horizon plus this).
        score_scale: Eq. 5's min and max over every run here ("sweep") or
            each run's own ("run").
        constant: a constant AV setting run on the same schedules as a third
            driver, "best_constant" (the means then over the vehicles
            arrived in all three).
        progress: progress bars in simulated time on stderr.

    Returns:
        ``{"scenario", "seeds", "policy": path, "layout": {...},
        "max_vehicles": M of the reported runs, "max_vehicles_tried": every
        M run, "jax_slot_overflow": vehicle-steps over all runs (0 unless
        the road itself overflowed),
        "cap_s": the longest a run went on, "jax_not_arrived": vehicles
        still in or waiting at the cap, over all runs, "outside_at_cap":
        [{"driver", "penetration", "seed", "not_arrived"}] of the runs that
        left any, "score_scale",
        "results": {driver: {penetration: metrics}}}`` where metrics are
        `jaxround.analysis.metrics.class_metrics` averaged over seeds, plus
        ``collisions`` and ``slot_overflow`` (means over seeds).

    Raises:
        ValueError: the policy reads other observations than the environment
            gives, or an unknown `score_scale`.
    """
    if score_scale not in SCORE_SCALES:
        raise ValueError(f"score_scale {score_scale!r}, expected one of {SCORE_SCALES}")
    runs = run_drivers(
        policy_path, cfg, penetrations, seeds, max_vehicles, drain_s, constant,
        progress,
    )  # fmt: skip
    result = summarise_drivers(runs, score_scale)
    if keep_records:
        result["records"] = runs.records
    return result


#: Columns of the printed comparison.
SUMMARY_COLUMNS = (
    "%AVs",
    "AVs driven by",
    "crossing AV (s)",
    "crossing HV (s)",
    "crossing all (s)",
    "CO2 g/veh",
    "fuel g/veh",
    "arrived",
    "collisions",
)


def summary_rows(results: dict[str, dict[float, dict[str, Any]]]) -> list[list[str]]:
    """Rows of `SUMMARY_COLUMNS`: per penetration, the policy, then the
    uncontrolled baseline, then the best constant where it was run."""
    from jaxround.analysis.report import percent_label

    def cell(x: Any, digits: int = 2) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    rows = []
    for p in sorted(results["policy"]):
        for driver in (d for d in (*DRIVERS, "best_constant") if d in results):
            m = results[driver][p]
            rows.append(
                [
                    percent_label(p),
                    driver,
                    cell(m["av"]["mean_crossing_time_s"]),
                    cell(m["hv"]["mean_crossing_time_s"]),
                    cell(m["all"]["mean_crossing_time_s"]),
                    cell(m["all"]["co2_g_per_veh"], 1),
                    cell(m["all"]["fuel_g_per_veh"], 1),
                    cell(m["all"]["n_arrived"], 0),
                    "n/a" if m["collisions"] is None else cell(m["collisions"], 0),
                ]
            )
    return rows


__all__ = [
    "DRIVERS",
    "SUMMARY_COLUMNS",
    "DriverRuns",
    "evaluate_policy",
    "run_drivers",
    "summarise_drivers",
    "summary_rows",
    "switched_policy",
    "with_observer",
]
