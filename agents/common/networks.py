"""The actor-critic every AV shares, and its action distribution.

One MLP reads one slot's observation row and gives

- a Gaussian over the acceleration command (mean per slot, one learned,
  state-independent log-std),
- logits over the lane-change decision: two (keep, change to the left: the
  paper's binary Eq. 2) or, on two-lane roads, three (no request, left,
  right; `lane_choices_for`),
- a value.

The forward pass is a pure function of ``(params, obs (M, D), mask (M,))``:
`policy_inputs` builds each row's input (optionally with the mean of the
other vehicles' rows), written once for both NumPy and JAX so the exported
policy (`agents.common.export`) computes exactly what was trained.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

#: Lane-change choices on one-lane roads: index 0 keep the lane (no request),
#: 1 change (the lane to the left).
N_LANE_CHOICES = 2
#: On two-lane roads: 0 no request (LC2013 decides), 1 left, 2 right.
N_LANE_CHOICES_TWO_LANE = 3
#: Initial logit of "no request" among three choices (the others 0): at
#: first 80% of an AV's steps leave the lane to LC2013, as uncontrolled, and
#: each request is tried in 10%; with equal logits two steps in three would
#: send a random request.
NO_REQUEST_LOGIT = math.log(8.0)
_LOG_2PI = math.log(2.0 * math.pi)


class PolicyOutput(NamedTuple):
    """What the network says about M slots (leading batch dims allowed).

    Attributes:
        accel_mean: float (..., M) mean acceleration command, m/s^2.
        log_std: float () log standard deviation of the command.
        lane_logits: float (..., M, C) logits of the C lane choices
            (`lane_column` says what each asks for).
        value: float (..., M) state value of each slot's vehicle.
    """

    accel_mean: jax.Array
    log_std: jax.Array
    lane_logits: jax.Array
    value: jax.Array


def activation(name: str, xp: ModuleType = jnp) -> Callable:
    """The activation called `name` ("tanh" or "relu") in NumPy or JAX."""
    if name == "tanh":
        return xp.tanh
    if name == "relu":
        return lambda x: xp.maximum(x, 0.0)
    raise ValueError(f"activation: {name!r}, expected 'tanh' or 'relu'")


def policy_inputs(obs, mask, centralised: bool, xp: ModuleType = jnp):
    """Each slot's network input, float (..., M, D) or (..., M, 2D).

    Args:
        obs: float (..., M, D) observation rows.
        mask: bool (..., M) slots that hold a vehicle.
        centralised: append to row i the mean of the rows of the *other*
            occupied slots (zeros when there are none): permutation-invariant
            information about the rest of the roundabout.
        xp: `numpy` or `jax.numpy`.

    Returns:
        The rows (obs itself when not centralised).
    """
    if not centralised:
        return obs
    m = mask.astype(obs.dtype)[..., None]  # (..., M, 1)
    own = obs * m
    total = own.sum(axis=-2, keepdims=True)  # (..., 1, D)
    count = m.sum(axis=-2, keepdims=True)  # (..., 1, 1)
    others = (total - own) / xp.maximum(count - m, 1.0)  # (..., M, D)
    return xp.concatenate([obs, others], axis=-1)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs over one slot's input row, shared by slots.

    Attributes:
        hidden: layer widths, e.g. (64, 64).
        activation: "tanh" or "relu".
        centralised: see `policy_inputs`.
        lane_choices: C, 2 (keep, left) or 3 (no request, left, right).
    """

    hidden: Sequence[int]
    activation: str = "tanh"
    centralised: bool = False
    lane_choices: int = N_LANE_CHOICES

    @nn.compact
    def __call__(self, obs: jax.Array, mask: jax.Array) -> PolicyOutput:
        """Args: obs float (..., M, D); mask bool (..., M). Returns `PolicyOutput`."""
        act = activation(self.activation)
        x = policy_inputs(obs, mask, self.centralised)
        init = nn.initializers.orthogonal

        a = x
        for i, width in enumerate(self.hidden):
            a = act(
                nn.Dense(width, kernel_init=init(math.sqrt(2)), name=f"actor_{i}")(a)
            )
        accel_mean = nn.Dense(1, kernel_init=init(0.01), name="accel_mean")(a)[..., 0]
        lane_logits = nn.Dense(
            self.lane_choices,
            kernel_init=init(0.01),
            bias_init=_lane_bias_init,
            name="lane_logits",
        )(a)
        log_std = self.param("log_std", nn.initializers.zeros, ())

        c = x
        for i, width in enumerate(self.hidden):
            c = act(
                nn.Dense(width, kernel_init=init(math.sqrt(2)), name=f"critic_{i}")(c)
            )
        value = nn.Dense(1, kernel_init=init(1.0), name="value")(c)[..., 0]
        return PolicyOutput(accel_mean, log_std, lane_logits, value)


def _lane_bias_init(key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32):
    """Zeros for two choices (as before); `NO_REQUEST_LOGIT` first for three."""
    del key
    bias = jnp.zeros(shape, dtype)
    three = shape[-1] == N_LANE_CHOICES_TWO_LANE
    return bias.at[0].set(NO_REQUEST_LOGIT) if three else bias


# --------------------------------------------------------------------------- actions


def log_prob(out: PolicyOutput, accel: jax.Array, change: jax.Array) -> jax.Array:
    """Joint log-probability of (acceleration, lane choice), float (..., M).

    Args:
        out: the network's output.
        accel: float (..., M) acceleration commands (before the env clips them).
        change: int (..., M) lane choice, 0 to C - 1.
    """
    z = (accel - out.accel_mean) * jnp.exp(-out.log_std)
    gauss = -0.5 * z**2 - out.log_std - 0.5 * _LOG_2PI
    lane = jax.nn.log_softmax(out.lane_logits)
    lane = jnp.take_along_axis(lane, change[..., None], axis=-1)[..., 0]
    return gauss + lane


def entropy(out: PolicyOutput) -> jax.Array:
    """Entropy of the joint action distribution, float (..., M)."""
    gauss = out.log_std + 0.5 * (1.0 + _LOG_2PI)
    logp = jax.nn.log_softmax(out.lane_logits)
    lane = -jnp.sum(jnp.exp(logp) * logp, axis=-1)
    return gauss + lane


def sample(
    out: PolicyOutput, key: jax.Array, noise: jax.Array | None = None
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Draw actions for every slot.

    Args:
        out: the network's output.
        key: PRNG key.
        noise: float (..., M) standard normal noise of the command to use
            (e.g. held over a vehicle's trip); drawn from `key` if None.

    Returns:
        (accel float (..., M), change int32 (..., M), log_prob float (..., M)).
    """
    k_a, k_l = jax.random.split(key)
    if noise is None:
        noise = jax.random.normal(k_a, out.accel_mean.shape, out.accel_mean.dtype)
    accel = out.accel_mean + jnp.exp(out.log_std) * noise
    change = jax.random.categorical(k_l, out.lane_logits).astype(jnp.int32)
    return accel, change, log_prob(out, accel, change)


def env_action(accel: jax.Array, change: jax.Array) -> jax.Array:
    """The environment's action, float (..., M, 2): command and lane column
    (`jaxround.envs.lane_view`) of the lane choice (`lane_column`)."""
    return jnp.stack([accel, lane_column(change).astype(accel.dtype)], axis=-1)


def lane_column(change, xp: ModuleType = jnp):
    """The lane column of a lane choice (int 0, 1, 2 or bool, (...,)): 1.0
    (ask for the lane to the left) for choice 1 (True), -1.0 (the lane to
    the right) for choice 2, NaN (no request: LC2013 decides) for 0 (False);
    `xp` is `jax.numpy` or `numpy`."""
    change = xp.asarray(change).astype(xp.int32)
    return xp.where(change == 1, 1.0, xp.where(change == 2, -1.0, xp.nan))


def lane_choices_for(multi_lane: bool) -> int:
    """C for a network on a scenario with (`multi_lane`) or without two-lane
    roads: 3 (no request, left, right) or 2 (keep, change: the paper's
    binary decision, whose "change" asks for the lane to the left)."""
    return N_LANE_CHOICES_TWO_LANE if multi_lane else N_LANE_CHOICES


def deterministic_action(
    accel_mean, lane_logits, bounds: tuple[float, float], xp: ModuleType = jnp
):
    """The policy's mode: the mean command clipped to `bounds`, the likelier lane.

    Args:
        accel_mean: float (..., M).
        lane_logits: float (..., M, C).
        bounds: (lowest, highest) command, m/s^2.
        xp: `numpy` or `jax.numpy`.

    Returns:
        (accel float (..., M), change int (..., M): the likeliest lane
        choice, the lowest index among equals).
    """
    accel = xp.clip(accel_mean, bounds[0], bounds[1])
    change = xp.argmax(lane_logits, axis=-1).astype(xp.int32)
    return accel, change


def n_inputs(obs_size: int, centralised: bool) -> int:
    """Width of a network input row."""
    return 2 * obs_size if centralised else obs_size


def init_params(
    network: ActorCritic, key: jax.Array, obs_size: int, max_vehicles: int
) -> dict:
    """Fresh parameters for rows of `obs_size` features."""
    obs = jnp.zeros((max_vehicles, obs_size), jnp.float32)
    return jax.jit(network.init)(key, obs, jnp.ones(max_vehicles, bool))


__all__ = [
    "N_LANE_CHOICES",
    "N_LANE_CHOICES_TWO_LANE",
    "NO_REQUEST_LOGIT",
    "ActorCritic",
    "PolicyOutput",
    "activation",
    "deterministic_action",
    "entropy",
    "env_action",
    "init_params",
    "lane_choices_for",
    "lane_column",
    "log_prob",
    "n_inputs",
    "policy_inputs",
    "sample",
]
