"""A traffic survey in the paper's form: per leg and per time slot, the mean
and the largest queue on the approach, the upstream flow (vehicles entering
from the leg) and the downstream flow (vehicles leaving by the leg).

Both simulators produce the same `Survey`: SUMO from its per-step halting
counts and trip records (`sumo_export.measure`), JAX from an episode
(`survey_episode`). A survey saved as JSON is the targets file of
`jaxround calibrate`.

Definitions, shared by both sides:
- a queue sample is taken after every step whose end time lies in the slot
  ``(k * slot_s, (k + 1) * slot_s]``: vehicles halting (below 0.1 m/s) on the
  leg's approach plus those due that wait to be inserted there;
- a flow counts the insertions (upstream) or arrivals (downstream) whose time
  lies in the slot, in vehicles per hour.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.dynamics import ARRIVAL_EPS
from jaxround.core.params import EnvParams
from jaxround.core.relax import soft_step
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.queues import queued_per_leg
from jaxround.envs.rollout import Policy, uncontrolled_policy
from jaxround.envs.roundabout import RoundaboutEnv
from jaxround.scenario.config import ConfigError

#: The paper's survey slots: 10 minutes.
SLOT_S = 600.0
#: What a survey holds per slot and leg, each float (n_slots, n_legs).
MEASURES = ("queue_mean_veh", "queue_max_veh", "upstream_veh_h", "downstream_veh_h")
FORMAT = "jaxround-survey/1"


@dataclass(frozen=True)
class Survey:
    """Per-slot, per-leg counts of one or more runs (means over the runs).

    Attributes:
        scenario: the scenario's name.
        legs: the legs' names, (n_legs,).
        slot_s: slot length, s.
        queue_mean_veh, queue_max_veh, upstream_veh_h, downstream_veh_h:
            float (n_slots, n_legs).
        seeds: the schedules' seeds the counts are averaged over.
        drivers: the human drivers' parameters of the runs (for the record).
        source: "sumo" or "jax".
        slot_overflow: JAX's vehicle-steps of insertions that waited for a
            free vehicle slot, over the runs (`jaxround.core.capacity`; 0 in SUMO).
    """

    scenario: str
    legs: tuple[str, ...]
    slot_s: float
    queue_mean_veh: np.ndarray
    queue_max_veh: np.ndarray
    upstream_veh_h: np.ndarray
    downstream_veh_h: np.ndarray
    seeds: tuple[int, ...] = ()
    drivers: dict[str, float] | None = None
    source: str = ""
    slot_overflow: int = 0

    @property
    def n_slots(self) -> int:
        return int(self.queue_mean_veh.shape[0])

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": FORMAT,
            "scenario": self.scenario,
            "source": self.source,
            "legs": list(self.legs),
            "slot_s": self.slot_s,
            "seeds": list(self.seeds),
            "drivers": self.drivers or {},
            "slot_overflow": self.slot_overflow,
        }
        for name in MEASURES:
            out[name] = np.round(getattr(self, name), 6).tolist()
        return out

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        return path


def load_survey(path: str | Path) -> Survey:
    """A survey (targets) file written by `Survey.save`; a clear error otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"targets file {path} does not exist")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"targets file {path} is not JSON: {e}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(
            f"targets file {path}: expected a '{FORMAT}' survey "
            "(written by `jaxround measure`)"
        )
    legs = data.get("legs")
    if not isinstance(legs, list) or not legs:
        raise ConfigError(f"targets file {path}: 'legs' must be a list of names")
    arrays = {}
    for name in MEASURES:
        try:
            arr = np.asarray(data[name], np.float64)
        except (KeyError, ValueError, TypeError):
            raise ConfigError(
                f"targets file {path}: '{name}' must be a table of numbers [slot][leg]"
            ) from None
        if arr.ndim != 2 or arr.shape[1] != len(legs) or arr.shape[0] == 0:
            raise ConfigError(
                f"targets file {path}: '{name}' has shape {arr.shape}, expected "
                f"(n_slots, {len(legs)})"
            )
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ConfigError(f"targets file {path}: '{name}' has negative or nan")
        arrays[name] = arr
    shapes = {a.shape for a in arrays.values()}
    if len(shapes) != 1:
        raise ConfigError(f"targets file {path}: tables of different shapes {shapes}")
    slot_s = data.get("slot_s")
    if not isinstance(slot_s, int | float) or slot_s <= 0:
        raise ConfigError(f"targets file {path}: 'slot_s' must be a positive number")
    return Survey(
        scenario=str(data.get("scenario", "")),
        legs=tuple(str(x) for x in legs),
        slot_s=float(slot_s),
        seeds=tuple(int(x) for x in data.get("seeds", [])),
        drivers={k: float(v) for k, v in (data.get("drivers") or {}).items()},
        source=str(data.get("source", "")),
        **arrays,
    )


def slot_flows(
    times: np.ndarray, legs: np.ndarray, n_legs: int, n_slots: int, slot_s: float
) -> np.ndarray:
    """Events per hour per slot and leg, float (n_slots, n_legs).

    Args:
        times: float (N,) event times (nan: no event).
        legs: int (N,) the leg of each event.
    """
    times = np.asarray(times, np.float64)
    ok = np.isfinite(times)
    slot = np.ceil(times[ok] / slot_s - 1e-9).astype(int) - 1
    keep = (slot >= 0) & (slot < n_slots)
    counts = np.zeros((n_slots, n_legs))
    np.add.at(counts, (slot[keep], np.asarray(legs)[ok][keep]), 1.0)
    return counts * 3600.0 / slot_s


def slot_queues(queues: jax.Array, steps_per_slot: int) -> tuple[jax.Array, jax.Array]:
    """Per-step queue samples (..., T, G) as per-slot (mean, max), each
    (..., T // steps_per_slot, G); works on numpy and JAX arrays."""
    *lead, t, g = queues.shape
    n_slots = t // steps_per_slot
    q = queues[..., : n_slots * steps_per_slot, :]
    q = q.reshape(*lead, n_slots, steps_per_slot, g)
    return q.mean(axis=-2), q.max(axis=-2)


def survey_rollout(
    env: RoundaboutEnv,
    params: EnvParams,
    schedule: Schedule,
    n_steps: int,
    policy: Policy | None = None,
    key: jax.Array | None = None,
) -> tuple[EnvState, jax.Array, jax.Array]:
    """An episode of `n_steps` from `schedule`: `measured_rollout` from the
    schedule's reset state."""
    obs, state = env.reset_to_schedule(schedule, params)
    return measured_rollout(env, params, obs, state, n_steps, policy, key)


def measured_rollout(
    env: RoundaboutEnv,
    params: EnvParams,
    obs: jax.Array,
    state: EnvState,
    n_steps: int,
    policy: Policy | None = None,
    key: jax.Array | None = None,
    remat: bool = True,
) -> tuple[EnvState, jax.Array, jax.Array]:
    """`n_steps` from `state`, with the survey's samples; differentiable in
    `params` (and in `state`'s floats).

    Pure and jit-able (`env`, `n_steps`, `policy`, `remat` static). With
    `remat` each step is rematerialised on the backward pass
    (`jax.checkpoint`), so memory grows with one state per step, not with
    the step's intermediates; short windows compile faster without it.

    Returns:
        (state, queues, in_network): the final state; float (T, G) the
        queue samples after each step (`queued_per_leg`, smooth in the
        halting test above temperature 0); float (T,) the vehicles in the
        network or waiting to enter during each step, each active one
        weighted by `soft_step(route end - position, temperature)` (m), so
        that ``dt * in_network.sum()`` is the total time of the trips (exact
        at temperature 0, smooth in the arrival above).
    """
    policy = uncontrolled_policy(env) if policy is None else policy
    key = jax.random.PRNGKey(0) if key is None else key
    temp = params.relax_temperature
    route_len = env.net.route_length

    def body(carry, step_key):
        obs, state = carry
        t = state.step.astype(jnp.float32) * env.dt
        due = (state.schedule.depart_s <= t + 1e-4) & ~state.inserted
        to_go = route_len[state.route] - ARRIVAL_EPS - state.pos
        on_road = jnp.sum(state.active * soft_step(to_go, temp))
        k_act, k_env = jax.random.split(step_key)
        action = policy(obs, state, k_act)
        obs, state, _, _, _ = env.step_env(k_env, state, action, params)
        q = queued_per_leg(env.net, state, t + env.dt, temp)
        return (obs, state), (q, on_road + jnp.sum(due))

    (_, state), (queues, in_network) = jax.lax.scan(
        jax.checkpoint(body) if remat else body,
        (obs, state),
        jax.random.split(key, n_steps),
    )
    return state, queues, in_network


def survey_steps(env: RoundaboutEnv, slot_s: float, n_slots: int) -> int:
    """Steps covering `n_slots` slots of `slot_s`; a clear error if a slot is
    not a whole number of steps."""
    per_slot = slot_s / env.dt
    if abs(per_slot - round(per_slot)) > 1e-6:
        raise ConfigError(
            f"slot of {slot_s} s is not a whole number of {env.dt} s steps"
        )
    return int(round(per_slot)) * n_slots


def jax_survey(
    env: RoundaboutEnv,
    params: EnvParams,
    schedules: Sequence[Schedule],
    seeds: Sequence[int],
    n_slots: int,
    slot_s: float = SLOT_S,
) -> Survey:
    """The survey of the JAX environment on `schedules` (exact dynamics
    unless ``params.relax_temperature > 0``), averaged over them."""
    n_steps = survey_steps(env, slot_s, n_slots)
    batch = jax.tree.map(lambda *x: jnp.stack(x), *schedules)
    run = jax.jit(
        jax.vmap(lambda s: survey_rollout(env, params, s, n_steps)[:2]),
    )
    state, queues = jax.device_get(run(batch))
    q_mean, q_max = slot_queues(np.asarray(queues, np.float64), n_steps // n_slots)
    g = env.n_legs
    up, down = [], []
    dest = np.asarray(env.route_destination)
    for b in range(len(schedules)):
        sched = jax.tree.map(lambda x, b=b: np.asarray(x[b]), state.schedule)
        insert = np.where(state.inserted[b], state.insert_s[b], np.nan)
        up.append(slot_flows(insert, sched.origin, g, n_slots, slot_s))
        down.append(
            slot_flows(state.arrival_s[b], dest[sched.route], g, n_slots, slot_s)
        )
    return Survey(
        scenario=env.cfg.name,
        legs=tuple(leg.name for leg in env.cfg.network.legs),
        slot_s=slot_s,
        queue_mean_veh=q_mean.mean(axis=0),
        queue_max_veh=q_max.mean(axis=0),
        upstream_veh_h=np.mean(up, axis=0),
        downstream_veh_h=np.mean(down, axis=0),
        seeds=tuple(int(s) for s in seeds),
        drivers=driver_numbers(params),
        source="jax",
        slot_overflow=int(np.sum(state.stats.overflow)),
    )


def driver_numbers(params: EnvParams) -> dict[str, float]:
    """The human drivers' calibrated numbers of `params`, plain floats."""
    return {name: float(params.human_number(name)) for name in CALIBRATABLE}


#: The driver parameters `jaxround calibrate` can fit (`EnvParams.with_human`).
CALIBRATABLE = (
    "accel",
    "decel",
    "tau",
    "min_gap",
    "delta",
    "jm_timegap_minor",
    "impatience",
)


def n_slots_for(duration_s: float, slot_s: float = SLOT_S) -> int:
    """Whole slots within the demand horizon."""
    return max(1, int(math.floor(duration_s / slot_s + 1e-9)))
