"""AV settings scored on many roundabouts at once: one compiled JAX program.

A *setting* is what a controller may choose for the AVs, five numbers in
`SPACE` order: the vType's headway ``tau`` (s), ``impatience``, maximum
acceleration ``accel`` (m/s^2), gap acceptance ``jm_timegap_minor`` (s), and
a cruise speed ``cruise_mps`` (m/s) commanded as the scripted ``cruise:V``
does (`jaxround.envs.scripted.cruise`); at `NO_CRUISE_MPS` or above no speed
is commanded (the AVs drive their vType). A setting is either the same for
every AV and every step (a *constant*, as a declared vType and ``cruise:V``
in SUMO) or, for ``tau``, ``impatience`` and ``cruise_mps``, chosen per AV
and step by a state-dependent controller (`jaxround.analysis.state_controller`).

`SearchProblem` holds one scenario's environment and departure schedules and
scores a batch of K settings (or controller parameters) on its S schedules
in one ``jit(vmap(vmap(...)))`` program, settings x schedules. Every episode
runs until all its vehicles have left (`run_steered`); the scores are per
schedule, over ALL vehicles that arrived (human drivers too):

- ``time_s``: mean crossing time (arrival minus scheduled departure), s;
- ``co2_g``: mean CO2 per vehicle, g;
- ``objective``: ``time_weight * time_s + co2_weight * co2_g``, the system
  reward's weights (1 per s, 0.5 per g by default); with
  ``Objective.charge_exit`` the time and CO2 still owed by vehicles that
  left below the speed limit (``exit_time_s``, ``exit_co2_g``,
  `jaxround.analysis.exit_debt`, from each vehicle's speed at the start of
  its last step) are added to both;
- ``missing``: scheduled vehicles that had not arrived when the episode hit
  its step limit (0 in a valid score);
- ``overflow``: insertions that waited for a free slot (0 in a valid score:
  otherwise the slots M were too few, `jaxround.envs.slots`).

Shapes: K settings, S schedules, M slots, D = 5 setting numbers.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxround.analysis.exit_debt import debt_table, exit_debt
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.roundabout import RoundaboutEnv, make
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import make_schedule

#: The numbers of a setting and their search bounds (low, high).
SPACE: dict[str, tuple[float, float]] = {
    "tau": (0.5, 2.0),
    "impatience": (0.0, 1.0),
    "accel": (1.5, 5.0),
    "jm_timegap_minor": (0.25, 2.0),
    "cruise_mps": (6.0, 14.0),
}
#: A cruise speed at or above this commands nothing: the legs' speed limit.
NO_CRUISE_MPS = 13.89
#: Seconds after the demand window an episode may run to let vehicles leave.
DRAIN_S = 600.0


@dataclass(frozen=True)
class Objective:
    """Cost of a vehicle's crossing: per second, per gram of CO2 and per
    near-conflict (SUMO's SSM count, one per vehicle of a pair)."""

    time_weight: float = 1.0
    co2_weight: float = 0.5
    charge_exit: bool = False  # add what slow leavers still owe
    conflict_weight: float = 0.0  # per conflict per vehicle

    def __call__(
        self, time_s: jax.Array, co2_g: jax.Array, conflicts_per_veh: jax.Array = 0.0
    ) -> jax.Array:
        return (
            self.time_weight * time_s
            + self.co2_weight * co2_g
            + self.conflict_weight * conflicts_per_veh
        )


def setting_of(values: dict[str, float]) -> np.ndarray:
    """float (D,) from names (missing ones: error), in `SPACE` order."""
    unknown = set(values) - set(SPACE)
    if unknown:
        raise ValueError(f"unknown setting number(s) {sorted(unknown)}; known {SPACE}")
    return np.array([float(values[name]) for name in SPACE], np.float32)


def vtype_setting(cfg: ScenarioConfig) -> np.ndarray:
    """float (D,): the scenario's own AV vType, without a speed command."""
    av = cfg.drivers.av
    own = {name: getattr(av, name) for name in SPACE if name != "cruise_mps"}
    return setting_of({**own, "cruise_mps": SPACE["cruise_mps"][1]})


def bounds(min_tau: float = 0.0) -> dict[str, tuple[float, float]]:
    """`SPACE` with tau's lower bound raised to the AVs' time-gap floor
    `min_tau` (`SafetyConfig.min_av_tau_s`), where that is higher."""
    low, high = SPACE["tau"]
    if min_tau >= high:
        raise ValueError(f"time-gap floor {min_tau} s: at or above tau's bound {high}")
    return {**SPACE, "tau": (max(low, float(min_tau)), high)}


def from_unit(unit: jax.Array, min_tau: float = 0.0) -> jax.Array:
    """Settings from points of the unit cube, float (..., D): each number
    ``low + (high - low) * clip(x, 0, 1)`` of `bounds`, so the bounds are
    reachable."""
    box = bounds(min_tau).values()
    low, high = (jnp.asarray(b, jnp.float32) for b in zip(*box, strict=True))
    return low + (high - low) * jnp.clip(unit, 0.0, 1.0)


def to_unit(setting: np.ndarray, min_tau: float = 0.0) -> np.ndarray:
    """The inverse of `from_unit` inside the bounds, float (..., D)."""
    box = bounds(min_tau).values()
    low, high = (np.asarray(b, np.float32) for b in zip(*box, strict=True))
    return (np.asarray(setting, np.float32) - low) / (high - low)


def describe(setting: Sequence[float]) -> dict[str, float | None]:
    """A setting as a dict; ``cruise_mps`` None where no speed is commanded."""
    out: dict[str, float | None] = {
        name: round(float(v), 4) for name, v in zip(SPACE, setting, strict=True)
    }
    if float(setting[-1]) >= NO_CRUISE_MPS:
        out["cruise_mps"] = None
    return out


def search_scenario(
    cfg: ScenarioConfig,
    window_s: float | None = None,
    demand_scale: float = 1.0,
    origin_share: Sequence[float] | None = None,
) -> ScenarioConfig:
    """The scenario's demand over a shorter window, scaled, or re-split.

    Args:
        window_s: seconds of demand (the config's if None), at the config's
            hourly rate times `demand_scale`.
        demand_scale: factor on the number of vehicles per second.
        origin_share: share of vehicles entering at each leg (the config's
            if None).
    """
    demand = cfg.demand
    window = demand.duration_s if window_s is None else float(window_s)
    rate = demand.n_vehicles / demand.duration_s * demand_scale
    new = dataclasses.replace(
        demand,
        duration_s=window,
        n_vehicles=max(1, round(rate * window)),
        origin_share=tuple(origin_share or demand.origin_share),
    )
    out = dataclasses.replace(cfg, demand=new)
    # settings command speeds (cruise), whatever the scenario's agent does
    out = dataclasses.replace(out, agent=dataclasses.replace(cfg.agent, action="accel"))
    out.validate()
    return out


@struct.dataclass
class SlotTunedParams(EnvParams):
    """`EnvParams` whose AVs drive with their own tau and impatience per slot.

    `for_vehicles` of the M slots reads ``slot_tau`` and ``slot_impatience``
    (float (M,)) for the AVs; for other shapes (the vehicles being inserted)
    it gives the vType's numbers, as SUMO inserts a vehicle with its vType's
    and a controller retunes it after the step.
    """

    slot_tau: jax.Array
    slot_impatience: jax.Array

    def for_vehicles(self, is_av: jax.Array):  # noqa: ANN201 - CarFollowing
        pv = super().for_vehicles(is_av)
        if jnp.shape(is_av) != jnp.shape(self.slot_tau):
            return pv
        return pv.replace(
            tau=jnp.where(is_av, self.slot_tau, pv.tau),
            impatience=jnp.where(is_av, self.slot_impatience, pv.impatience),
        )


def with_setting(params: EnvParams, setting: jax.Array) -> EnvParams:
    """The params with the AV vType's numbers of a setting (D,) (traced)."""
    named = dict(zip(SPACE, setting, strict=False))
    named.pop("cruise_mps", None)
    return params.replace(av=params.av.replace(**named))


def cruise_action(speed: jax.Array, cruise_mps: jax.Array, dt_s: float) -> jax.Array:
    """The env's action (M, 2): ``cruise:V`` per slot (``(V - v) / dt``, as
    `jaxround.envs.scripted.cruise`), none at `NO_CRUISE_MPS` and above.

    Args:
        speed: float (M,) each slot's speed, m/s.
        cruise_mps: float () or (M,) cruise speeds.
    """
    accel = (cruise_mps - speed) / dt_s
    accel = jnp.where(cruise_mps >= NO_CRUISE_MPS, jnp.nan, accel)
    return jnp.stack([accel, jnp.full_like(accel, jnp.nan)], axis=1)


#: steer(state) -> (params of this step, action (M, 2)).
Steer = Callable[[EnvState], tuple[EnvParams, jax.Array]]


def run_steered(
    env: RoundaboutEnv, schedule: Schedule, params: EnvParams, steer: Steer
) -> tuple[EnvState, jax.Array]:
    """Run from `schedule` until every vehicle has left or the episode's
    steps are spent; each step `steer` chooses the params and the action.
    (`jaxround.envs.rollout.run_until_left`, with params that may change.)

    Returns:
        (final state, exit speeds float (N,)): each vehicle's speed at the
        start of the step in which it left, m/s (NaN if it did not).
    """
    _, state = env.reset_to_schedule(schedule, params)
    key = jax.random.PRNGKey(0)  # the exact step draws nothing
    exit_speed = jnp.full(state.arrival_s.shape, jnp.nan, jnp.float32)

    def running(carry: tuple[EnvState, jax.Array]) -> jax.Array:
        state = carry[0]
        left = jnp.all(~jnp.isnan(state.arrival_s))
        return (state.step < env.episode_steps) & ~left

    def body(carry: tuple[EnvState, jax.Array]) -> tuple[EnvState, jax.Array]:
        state, exit_speed = carry
        step_params, action = steer(state)
        new = env.step_env(key, state, action, step_params)[1]
        vid = jnp.maximum(state.vid, 0)
        left_now = state.active & ~jnp.isnan(new.arrival_s[vid])
        where = jnp.where(left_now, state.vid, exit_speed.shape[0])  # else dropped
        return new, exit_speed.at[where].set(state.speed, mode="drop")

    return jax.lax.while_loop(running, body, (state, exit_speed))


def episode_scores(
    state: EnvState,
    exit_speed: jax.Array,
    objective: Objective,
    debt: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> dict[str, jax.Array]:
    """Scores of a finished episode (module docstring), float ().

    Args:
        exit_speed: float (N,) from `run_steered`.
        debt: `exit_debt.debt_table` of the exit legs' speed limit.
    """
    arrival = state.arrival_s
    arrived = ~jnp.isnan(arrival)
    n = jnp.maximum(jnp.sum(arrived), 1)

    def mean(x: jax.Array) -> jax.Array:
        return jnp.sum(jnp.where(arrived, x, 0.0)) / n

    time_s = mean(arrival - state.schedule.depart_s)
    co2_g = mean(state.stats.trip_co2_mg) / 1000.0
    owed_co2, owed_time = exit_debt(jnp.nan_to_num(exit_speed), debt)
    exit_co2_g, exit_time_s = mean(owed_co2), mean(owed_time)
    # per scheduled vehicle, as the reports' conflicts per 1,000 vehicles
    conflicts = jnp.sum(state.stats.conflicts) / state.stats.conflicts.shape[-1]
    charged = objective(time_s + exit_time_s, co2_g + exit_co2_g, conflicts)
    plain = objective(time_s, co2_g, conflicts)
    return {
        "objective": charged if objective.charge_exit else plain,
        "time_s": time_s,
        "co2_g": co2_g,
        "conflicts_per_1000": 1000.0 * conflicts,
        "exit_time_s": exit_time_s,
        "exit_co2_g": exit_co2_g,
        "missing": jnp.sum(~arrived),
        "overflow": state.stats.overflow,
    }


class SearchProblem:
    """One scenario, its schedules and an objective; scores batches of settings.

    Args:
        cfg: the scenario (`search_scenario` for a shorter window).
        penetration: share of AVs.
        seeds: the schedules' seeds (search: 200 and above; final checks:
            100 and above; training draws its own in JAX).
        objective: the weights of time and CO2.
        max_vehicles: slots M (None: sized by the scenario's traffic).
        rows: settings scored per call of a compiled program (None: a
            batch's own K). With a fixed number, batches of any K, and
            schedules of any count (in blocks of ``len(seeds)``, also after
            `with_seeds`), reuse one program per controller kind instead of
            compiling one per shape; padding rows and schedules are scored
            and dropped.
    """

    def __init__(
        self,
        cfg: ScenarioConfig,
        penetration: float,
        seeds: Sequence[int],
        objective: Objective = Objective(),
        max_vehicles: int | str | None = None,
        rows: int | None = None,
    ) -> None:
        if rows is not None and rows < 1:
            raise ValueError(f"rows: {rows!r}, expected at least 1")
        self.cfg = cfg
        self.min_tau = cfg.safety.min_av_tau_s  # the AVs' time-gap floor
        self.penetration = float(penetration)
        self.objective = objective
        self.rows = rows
        self.seed_block = len(seeds) if rows is not None else None
        self.env, self.params = make(
            cfg, max_vehicles=max_vehicles, episode_s=cfg.demand.duration_s + DRAIN_S
        )
        limit = max(leg.speed_limit_mps for leg in cfg.network.legs)
        self.debt = debt_table(limit)
        self._use_seeds(seeds)
        self._compiled: dict[str, Callable] = {}

    def _use_seeds(self, seeds: Sequence[int]) -> None:
        self.seeds = [int(s) for s in seeds]
        self.numpy_schedules = [
            make_schedule(self.cfg, seed=s, penetration=self.penetration)
            for s in self.seeds
        ]
        one = [self.env.schedule_from_numpy(s) for s in self.numpy_schedules]
        self.schedules = jax.tree.map(lambda *x: jnp.stack(x), *one)

    def with_seeds(self, seeds: Sequence[int]) -> SearchProblem:
        """The same environment and compiled programs on other schedules (a
        program compiled for S schedules serves any S' = S without compiling)."""
        other = copy.copy(self)
        other._use_seeds(seeds)
        return other

    def score(
        self, name: str, steer_of: Callable[[jax.Array], Steer], batch: jax.Array
    ) -> dict[str, np.ndarray]:
        """Scores (K, S) of a batch (K, P) of controller parameters, where
        ``steer_of(theta)`` is the controller of one row (compiled once per
        `name`)."""
        if name not in self._compiled:

            def one(theta: jax.Array, schedule: Schedule) -> dict[str, jax.Array]:
                state, exit_speed = run_steered(
                    self.env, schedule, self.params, steer_of(theta)
                )
                return episode_scores(state, exit_speed, self.objective, self.debt)

            per_seed = jax.vmap(one, in_axes=(None, 0))
            self._compiled[name] = jax.jit(jax.vmap(per_seed, in_axes=(0, None)))
        program = self._compiled[name]
        batch = np.asarray(batch, np.float32)
        k, s = batch.shape[0], len(self.seeds)
        if self.rows is None:
            out = program(jnp.asarray(batch), self.schedules)
            return {key: np.asarray(v) for key, v in jax.device_get(out).items()}
        rows, cols = self.rows, self.seed_block
        batch = batch[np.minimum(np.arange(-(-k // rows) * rows), k - 1)]
        seeds = np.minimum(np.arange(-(-s // cols) * cols), s - 1)
        blocks = []  # (row block, seed block) dicts of (rows, cols)
        for i in range(0, len(batch), rows):
            along = []
            for j in range(0, len(seeds), cols):
                take = jnp.asarray(seeds[j : j + cols])
                schedules = jax.tree.map(lambda x, t=take: x[t], self.schedules)
                along.append(jax.device_get(program(batch[i : i + rows], schedules)))
            blocks.append({key: np.concatenate([a[key] for a in along], 1)
                           for key in along[0]})  # fmt: skip
        return {
            key: np.concatenate([b[key] for b in blocks], 0)[:k, :s]
            for key in blocks[0]
        }

    def constant_steer(self, setting: jax.Array) -> Steer:
        """The controller of a constant setting (D,)."""
        params = with_setting(self.params, setting)

        def steer(state: EnvState) -> tuple[EnvParams, jax.Array]:
            return params, cruise_action(state.speed, setting[-1], self.env.dt)

        return steer

    def score_settings(self, settings: np.ndarray) -> dict[str, np.ndarray]:
        """Scores (K, S) of constant settings float (K, D)."""
        return self.score("constant", self.constant_steer, settings)
