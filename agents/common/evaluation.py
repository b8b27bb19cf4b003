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
from jaxround.analysis.metrics import (
    SCORE_SCALES,
    arrived_in_all,
    class_metrics,
    mean_over_runs,
    sweep_scale,
)
from jaxround.core.capacity import road_capacity
from jaxround.core.state import EnvState
from jaxround.envs.rollout import NO_COMMAND, Policy, run_until_left, vehicle_records
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.envs.slots import redo_on_overflow
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
        change = jnp.where(use_policy, change, False)
        return jnp.stack([accel, change.astype(jnp.float32)], axis=-1)

    return act


def evaluate_policy(
    policy_path: str | Path,
    cfg: ScenarioConfig,
    penetrations: Sequence[float],
    seeds: Sequence[int],
    max_vehicles: int | str | None = None,
    keep_records: bool = False,
    drain_s: float = DRAIN_S,
    score_scale: str = "sweep",
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

        def one(schedule: Any, key: jax.Array, flag: jax.Array) -> EnvState:
            policy = switched_policy(weights, layout, flag)
            return run_until_left(env, params, schedule, key, policy)

        return env, jax.jit(jax.vmap(one))(batch, keys, use_policy)

    (env, states), tried = redo_on_overflow(
        run_with, lambda run: int(np.sum(run[1].stats.overflow)),
        max_vehicles=env.max_vehicles, road=road_capacity(env.network, cfg),
        what="evaluate (JAX)",
    )  # fmt: skip
    records: dict[str, dict[float, list[Any]]] = {d: {} for d in DRIVERS}
    finals = []
    for i, (driver, p, _) in enumerate(runs):
        state = jax.tree.map(lambda x, i=i: x[i], states)
        records[driver].setdefault(p, []).append(vehicle_records(env, state))
        finals.append(state.stats)
    # the policy and the baseline over the same vehicles: those arrived in both
    compared = {
        (p, k): arrived_in_all(records[d][p][k] for d in DRIVERS)
        for p in penetrations
        for k in range(len(seeds))
    }
    every = [r for by_p in records.values() for rs in by_p.values() for r in rs]
    scale = sweep_scale(every) if score_scale == "sweep" else None
    per_run: dict[tuple[str, float], list[dict[str, Any]]] = {}
    overflow = not_arrived = 0
    outside: list[dict[str, Any]] = []
    horizon = cfg.demand.duration_s
    for i, (driver, p, seed) in enumerate(runs):
        k = list(seeds).index(seed)
        rec = records[driver][p][k]
        m = class_metrics(rec, horizon, compared=compared[(p, k)], scale=scale)
        m["collisions"] = int(finals[i].collisions)
        m["slot_overflow"] = int(finals[i].overflow)
        overflow += m["slot_overflow"]
        left = m["all"]["n_not_arrived"]
        not_arrived += left
        if left:
            outside.append(
                {"driver": driver, "penetration": p, "seed": seed, "not_arrived": left}
            )
        per_run.setdefault((driver, p), []).append(m)
    result = {
        "scenario": cfg.name,
        "seeds": list(seeds),
        "policy": str(policy_path),
        "layout": {
            "observer": layout.observer,
            "obs_size": layout.obs_size,
            "hidden": list(layout.hidden),
            "centralised": layout.centralised,
        },
        "max_vehicles": env.max_vehicles,
        "max_vehicles_tried": tried,
        "jax_slot_overflow": overflow,
        "cap_s": cap_s,
        "jax_not_arrived": not_arrived,
        "outside_at_cap": outside,
        "score_scale": score_scale,
        "results": {
            d: {p: mean_over_runs(per_run[(d, p)]) for p in penetrations}
            for d in DRIVERS
        },
    }
    if keep_records:
        result["records"] = records
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
    """Rows of `SUMMARY_COLUMNS`: per penetration, the policy then the baseline."""
    from jaxround.analysis.report import percent_label

    def cell(x: Any, digits: int = 2) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    rows = []
    for p in sorted(results["policy"]):
        for driver in DRIVERS:
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
    "evaluate_policy",
    "summary_rows",
    "switched_policy",
    "with_observer",
]
