"""Whole episodes by `lax.scan` or until every vehicle has left (one run, or
a batch in chunks with a progress bar), and their per-vehicle records for
the metrics."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.roundabout import RoundaboutEnv
from jaxround.scenario.records import VehicleRecords

#: policy(obs, state, key) -> action (M, 2)
Policy = Callable[[jax.Array, EnvState, jax.Array], jax.Array]


#: The action of an AV without a command: it drives its own vType.
NO_COMMAND = float("nan")


def uncontrolled_policy(env: RoundaboutEnv) -> Policy:
    """AVs drive their own vType (IDM, LC2013) as SUMO does without a
    controller: no speed command and no lane request (NaN,
    `jaxround.envs.actions.command_from_action`, `jaxround.envs.lane_view`).
    Human drivers ignore the action."""

    def act(obs: jax.Array, state: EnvState, key: jax.Array) -> jax.Array:
        del obs, state, key
        return jnp.full((env.max_vehicles, 2), NO_COMMAND, jnp.float32)

    return act


def run_episode(
    env: RoundaboutEnv,
    params: EnvParams,
    schedule: Schedule,
    key: jax.Array,
    policy: Policy | None = None,
    n_steps: int | None = None,
) -> EnvState:
    """Run one episode from `schedule` without auto-reset; return the final state.

    Without a `policy`, AVs drive uncontrolled (`uncontrolled_policy`).

    Pure and jit-able (jit with `env`, `policy` and `n_steps` static, e.g. via
    `make_episode_runner`); vmap over `schedule`, `params` or `key` for batches.
    """
    policy = uncontrolled_policy(env) if policy is None else policy
    n_steps = env.episode_steps if n_steps is None else n_steps
    obs, state = env.reset_to_schedule(schedule, params)

    def body(carry, step_key):
        obs, state = carry
        k_act, k_env = jax.random.split(step_key)
        action = policy(obs, state, k_act)
        obs, state, _, _, _ = env.step_env(k_env, state, action, params)
        return (obs, state), None

    (_, state), _ = jax.lax.scan(body, (obs, state), jax.random.split(key, n_steps))
    return state


def run_until_left(
    env: RoundaboutEnv,
    params: EnvParams,
    schedule: Schedule,
    key: jax.Array,
    policy: Policy | None = None,
    max_steps: int | None = None,
) -> EnvState:
    """Run from `schedule` until every scheduled vehicle has left, or
    `max_steps` (default: the episode length), whichever comes first.

    As `run_episode`, but a `lax.while_loop` that stops early, so parity and
    evaluation can compare the same vehicles with a simulator that also runs
    until the last one leaves. Under `vmap` the batch runs until its last
    member is done. ``state.step`` tells where it stopped.
    """
    policy = uncontrolled_policy(env) if policy is None else policy
    max_steps = env.episode_steps if max_steps is None else max_steps
    obs, state = env.reset_to_schedule(schedule, params)
    return _advance(env, params, policy, (obs, state, key), max_steps)[1]


def _advance(
    env: RoundaboutEnv,
    params: EnvParams,
    policy: Policy,
    carry: tuple[jax.Array, EnvState, jax.Array],
    until: jax.Array | int,
) -> tuple[jax.Array, EnvState, jax.Array]:
    """Step ``carry`` = (obs, state, key) until every scheduled vehicle has
    left or ``state.step`` reaches ``until`` (a `lax.while_loop`)."""

    def running(carry: tuple) -> jax.Array:
        _, state, _ = carry
        left = jnp.all(~jnp.isnan(state.arrival_s))
        return (state.step < until) & ~left

    def body(carry: tuple) -> tuple:
        obs, state, key = carry
        key, k_act, k_env = jax.random.split(key, 3)
        action = policy(obs, state, k_act)
        obs, state, _, _, _ = env.step_env(k_env, state, action, params)
        return obs, state, key

    return jax.lax.while_loop(running, body, carry)


def runs_until_left(
    env: RoundaboutEnv,
    params: EnvParams,
    schedules: Schedule,
    keys: jax.Array,
    policy_of: Callable[[jax.Array], Policy],
    flags: jax.Array,
    desc: str | None = None,
    chunk_s: float = 120.0,
) -> EnvState:
    """`run_until_left` for B runs side by side, in jitted chunks of
    ``chunk_s`` simulated seconds, with a progress bar in simulated time.

    The same runs as ``jax.vmap(run_until_left)``: one `while_loop` cut
    into several with the same body, the same trips and every integer of
    the state to the bit, its float sums to rounding (XLA compiles the
    chunks apart; `tests/unit/test_rollout.py`).

    Args:
        schedules: B schedules, batched; keys: (B, 2) their keys.
        policy_of: the policy of a run from its flag; flags: (B,) one each.
        desc: the progress bar's label (None: no bar).

    Returns:
        the final states, batched over B.
    """
    max_steps = env.episode_steps

    def start(schedule: Schedule, key: jax.Array) -> tuple:
        obs, state = env.reset_to_schedule(schedule, params)
        return obs, state, key

    def advance(carry: tuple, flag: jax.Array, until: jax.Array) -> tuple:
        return _advance(env, params, policy_of(flag), carry, until)

    carry = jax.jit(jax.vmap(start))(schedules, keys)
    step = jax.jit(jax.vmap(advance, in_axes=(0, 0, None)))
    chunk = max(1, int(round(chunk_s / env.dt)))
    total_s = max_steps * env.dt
    with tqdm(total=round(total_s), unit="s", desc=desc, disable=desc is None,
              leave=False) as bar:  # fmt: skip
        until = 0
        while until < max_steps:
            until = min(until + chunk, max_steps)
            carry = step(carry, flags, jnp.int32(until))
            bar.update(round(until * env.dt) - bar.n)
            if bool(jnp.all(~jnp.isnan(carry[1].arrival_s))):
                break
    return carry[1]


def make_episode_runner(
    env: RoundaboutEnv, policy: Policy | None = None, n_steps: int | None = None
) -> Callable[[EnvParams, Schedule, jax.Array], EnvState]:
    """A jitted `run_episode(params, schedule, key)` for this environment."""

    def run(params: EnvParams, schedule: Schedule, key: jax.Array) -> EnvState:
        return run_episode(env, params, schedule, key, policy, n_steps)

    return jax.jit(run)


def vehicle_records(env: RoundaboutEnv, state: EnvState) -> VehicleRecords:
    """The metrics' `VehicleRecords` of a finished (unbatched) episode."""
    s = jax.device_get(state)
    samples = max(int(s.stats.queue_samples), 1)
    nan = np.isnan
    co2 = np.asarray(s.stats.trip_co2_mg, np.float64) / 1000.0
    fuel = np.asarray(s.stats.trip_fuel_mg, np.float64) / 1000.0
    arrival = np.asarray(s.arrival_s, np.float64)
    conflicts = np.asarray(s.stats.conflicts, np.int64)
    # as SUMO's SSM log: TTC and DRAC of the vehicles with a conflict
    in_conflict = conflicts > 0
    return VehicleRecords(
        is_av=np.asarray(s.schedule.is_av, bool),
        origin=np.asarray(s.schedule.origin),
        scheduled_depart_s=np.asarray(s.schedule.depart_s, np.float64),
        depart_s=np.asarray(s.insert_s, np.float64),
        arrival_s=arrival,
        co2_g=np.where(nan(arrival), np.nan, co2),
        fuel_g=np.where(nan(arrival), np.nan, fuel),
        queue_mean_veh=np.asarray(s.stats.queue_sum, np.float64) / samples,
        queue_max_veh=np.asarray(s.stats.queue_max, np.float64),
        conflicts=conflicts,
        min_ttc_s=np.where(in_conflict, np.asarray(s.stats.min_ttc_s), np.nan),
        max_drac_mps2=np.where(in_conflict, np.asarray(s.stats.max_drac_mps2), np.nan),
        lane_changes=None if s.lanes is None else np.asarray(s.lanes.changes, np.int64),
    )
