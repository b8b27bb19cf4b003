"""A small state-dependent AV controller: settings as functions of the state.

Each AV, each step, chooses three numbers of its setting (`SPACE` of
`jaxround.analysis.setting_search`): ``tau``, ``impatience`` and
``cruise_mps``, each in its search bounds as

    number = low + (high - low) * clip(bias + weights . features, 0, 1)

of `FEATURES`, each about in [0, 1]: six numbers of the rich observation
(`jaxround.envs.observe`): own speed, the gap to the leader, the distance to
the yield line, how soon the ring traffic reaches the entry, how far round
the ring the exit is and the time waited; whether the vehicle ahead is a
human driver (1) or an AV or no one (0), which matters in mixed traffic;
and how fast the vehicle closes in on its leader and how hard that leader
braked in the last step, which tell a safe short gap from an unsafe one. ``accel`` and
``jm_timegap_minor`` stay those of a constant setting (a vType's, which a
SUMO controller cannot retune each step). With all weights 0 the controller
is that constant setting: the search starts there (`start_of`), so it is
never worse on the search's schedules.

theta: float (P,) = (`TUNED` x (1 + `FEATURES`)), row-major, P = 30.
tau never goes below the AVs' time-gap floor (`bounds`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.analysis.setting_search import (
    SPACE,
    SearchProblem,
    SlotTunedParams,
    Steer,
    bounds,
    cruise_action,
    to_unit,
    with_setting,
)
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.observe import rich_observation_and_leader
from jaxround.envs.scripted import LEADER_GAP, OWN_SPEED, RING_ARRIVAL, TO_YIELD_LINE

#: Rich-observation columns of the exit's legs round the ring over the legs,
#: and of the time waited over the time to impatience (`observe`'s order).
LEGS_TO_EXIT, WAITING = 15, 16
#: Rich-observation columns the controller reads.
OBSERVED = {
    "own_speed": OWN_SPEED,
    "leader_gap": LEADER_GAP,
    "to_yield_line": TO_YIELD_LINE,
    "ring_arrival": RING_ARRIVAL,
    "legs_to_exit": LEGS_TO_EXIT,
    "waiting": WAITING,
}
#: The controller's inputs: `OBSERVED`, whether the leader is human, how
#: fast the vehicle closes in on it and how hard it brakes (safety's inputs).
FEATURES = (*OBSERVED, "leader_is_human", "closing_speed", "leader_braking")
#: Scales of the last two features: the legs' speed limit (m/s) and the
#: drivers' decel (m/s^2), so that they are about in [0, 1].
CLOSING_SCALE_MPS, BRAKING_SCALE_MPS2 = 13.89, 4.3
#: The setting numbers chosen per AV and step.
TUNED = ("tau", "impatience", "cruise_mps")
N_PARAMS = len(TUNED) * (1 + len(FEATURES))


def start_of(setting: np.ndarray, min_tau: float = 0.0) -> np.ndarray:
    """theta (P,) of the controller that is the constant `setting` (D,)
    (`min_tau`: the time-gap floor of the box, `bounds`)."""
    unit = to_unit(setting, min_tau)
    names = list(SPACE)
    theta = np.zeros((len(TUNED), 1 + len(FEATURES)), np.float32)
    theta[:, 0] = [unit[names.index(n)] for n in TUNED]
    return theta.reshape(-1)


def features_of(obs: jax.Array, leader: jax.Array, state: EnvState) -> jax.Array:
    """`FEATURES` of each slot, float (M, F).

    Args:
        obs: float (M, 17) rich observation rows.
        leader: int (M,) slot ahead, -1 for none.
        state: the slots' class, speed and last acceleration, (M,).
    """
    has = leader >= 0
    lead = jnp.maximum(leader, 0)
    behind_human = has & ~state.is_av[lead]
    closing = jnp.where(has, jnp.maximum(state.speed - state.speed[lead], 0.0), 0.0)
    braking = jnp.where(has, jnp.maximum(-state.accel[lead], 0.0), 0.0)
    extra = jnp.stack(
        [behind_human, closing / CLOSING_SCALE_MPS, braking / BRAKING_SCALE_MPS2], -1
    ).astype(obs.dtype)
    return jnp.concatenate([obs[:, list(OBSERVED.values())], extra], -1)


def tuned_numbers(
    theta: jax.Array, feats: jax.Array, min_tau: float = 0.0
) -> dict[str, jax.Array]:
    """Each slot's `TUNED` numbers, name -> float (M,).

    Args:
        theta: float (P,).
        feats: float (M, F) `features_of` each slot.
        min_tau: the AVs' time-gap floor (`bounds`).
    """
    table = theta.reshape(len(TUNED), 1 + len(FEATURES))
    unit = jnp.clip(table[:, 0] + feats @ table[:, 1:].T, 0.0, 1.0)  # (M, 3)
    box = bounds(min_tau)
    out = {}
    for j, name in enumerate(TUNED):
        low, high = box[name]
        out[name] = low + (high - low) * unit[:, j]
    return out


def slot_params(params: EnvParams, tau: jax.Array, impatience: jax.Array):  # noqa: ANN201
    """`SlotTunedParams` of `params` with these per-slot numbers (M,)."""
    fields = {f.name: getattr(params, f.name) for f in dataclasses.fields(EnvParams)}
    return SlotTunedParams(**fields, slot_tau=tau, slot_impatience=impatience)


def controller_steer(
    problem: SearchProblem, setting: np.ndarray
) -> callable:  # theta -> Steer
    """``steer_of(theta)`` for `SearchProblem.score`: the controller of theta
    on the vType of the constant `setting` (D,) (its accel and gap acceptance)."""
    env = problem.env
    if env.max_vehicles == env.n_legs:  # SlotTunedParams tells slots by shape
        raise ValueError("controller_steer: needs more slots than legs")
    base = with_setting(problem.params, jnp.asarray(setting, jnp.float32))

    def steer_of(theta: jax.Array) -> Steer:
        def steer(state: EnvState) -> tuple[EnvParams, jax.Array]:
            obs, leader = rich_observation_and_leader(
                env.net, state, base, env.route_destination
            )
            feats = features_of(obs, leader, state)
            n = tuned_numbers(theta, feats, problem.min_tau)
            params = slot_params(base, n["tau"], n["impatience"])
            return params, cruise_action(state.speed, n["cruise_mps"], env.dt)

        return steer

    return steer_of


def score_controllers(
    problem: SearchProblem, setting: np.ndarray, thetas: np.ndarray
) -> dict[str, np.ndarray]:
    """Scores (K, S) of K controllers float (K, P) on the vType of `setting`.
    (One compiled program per problem and setting.)"""
    name = "state:" + ",".join(f"{v:.6g}" for v in np.asarray(setting))
    return problem.score(name, controller_steer(problem, setting), thetas)


def ablations(theta: np.ndarray) -> dict[str, np.ndarray]:
    """theta (P,) and its parts: which numbers' state dependence matters.
    ``"full"`` theta; ``"bias_only"`` all weights 0 (the constant it holds);
    ``"<name>_only"`` the weights of that number alone kept."""
    table = np.asarray(theta, np.float32).reshape(len(TUNED), 1 + len(FEATURES))
    out = {"full": table.reshape(-1)}
    for keep in (None, *TUNED):
        t = table.copy()
        t[[j for j, n in enumerate(TUNED) if n != keep], 1:] = 0.0
        out["bias_only" if keep is None else f"{keep}_only"] = t.reshape(-1)
    return out
