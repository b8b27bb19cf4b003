"""Scripted AV controllers: fixed rules on the rich observation, no training.

Each controller maps the ``"rich"`` observation rows (`jaxround.envs.observe`,
17 numbers per slot) to an acceleration command per slot, as a trained
policy does; the environment (and SUMO's `sumo_export.controller`) clips the
command to the AV's [-decel, accel] and applies it as SUMO applies a speed
command under speed mode 31 (`jaxround.core.command`): never above the AV's safe
(IDM) speed.
Where a rule has nothing to say it gives `NO_COMMAND` (NaN): the AV drives
its own vType exactly, as if uncontrolled.

Specs, as accepted wherever a controller is named:

- ``accel:A``: a constant acceleration command, A m/s^2.
- ``cruise:V``: a command toward the speed V m/s, ``(V - v) / dt``.
- ``eco[:B]``: coast when a stop is certain. A stop is certain behind a
  standing leader, or at the yield line when the ring traffic will be at the
  entry when this vehicle gets there. Then the AV brakes evenly to the stop
  point (``v^2 / (2 d)``) as soon as that rate reaches B m/s^2 (default
  0.3), instead of cruising on and braking late: below the speed limit every
  deceleration of B >= 0.3 m/s^2 lies within the fuel cut of SUMO's HBEFA
  model (``a < -0.108 - 0.013 v``), so the approach emits nothing.
- ``timed[:H]``: meet the gap rolling. When the ring traffic will be at the
  entry when this vehicle gets there, it slows evenly so as to reach the
  yield line H s (default 3) after the ring vehicle reaches the entry,
  at the speed ``2 d / T - v`` that covers the distance d in that time T.

A lane rule (``inner``, ``outer``, ``gap:X``: `jaxround.envs.scripted_lanes`)
may follow a speed rule after ``+`` (``eco+gap:5``) or stand alone
(``inner``: no speed command); such a controller reads the ``"lanes"``
observer (the rich one and 7 lane numbers) and also gives the action's
lane column.

Shapes: M slots. Every controller is a pure function of the rows, jit- and
vmap-able; rows of empty slots (all zeros) get a command that is ignored.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from jaxround.envs.observe import DISTANCE_SCALE, RING_HORIZON_S, SPEED_SCALE
from jaxround.envs.rollout import NO_COMMAND
from jaxround.envs.scripted_lanes import LANE_RULES, lane_choice, parse_lane_rule

#: Columns of the rich observation read here (`observe.rich_observation`).
OWN_SPEED = 10  # speed / SPEED_SCALE
LEADER_GAP = 11  # gap to the leader / DISTANCE_SCALE, 1 without a leader
LEADER_REL_SPEED = 12  # (leader's speed - own) / SPEED_SCALE
TO_YIELD_LINE = 13  # distance to the yield line / DISTANCE_SCALE, in [-1, 1]
RING_ARRIVAL = 14  # the ring traffic's soonest arrival / RING_HORIZON_S, <= 1
#: A leader slower than this, m/s, is standing: a stop behind it is certain.
STANDING_SPEED = 0.5
#: Distance kept to a standing leader, m: SUMO's default minGap.
STOP_GAP_M = 2.5
#: A vehicle blocked at a minor link stops this far before the line, m
#: (SUMO's MSVehicle::planMoveInternal).
LINE_MARGIN_M = 0.1
#: Seconds an AV needs between its arrival at the yield line and the ring
#: vehicle's, to enter first: crossing the entry and the AV's 1 s time gap.
GO_FIRST_S = 2.0
#: Seconds after the ring vehicle reaches the entry until it has passed and
#: the AV's 1 s time gap has run (the `eco` window; `timed`'s default H).
RING_CLEAR_S = 3.0
#: Default coasting threshold of ``eco``, m/s^2.
ECO_DECEL = 0.3

#: ``act(obs (M, 17)) -> command (M,)``.
ActFn = Callable[[jax.Array], jax.Array]


@dataclass(frozen=True)
class ScriptedController:
    """A scripted controller (see the module docstring for the specs).

    Attributes:
        spec: the controller's spec, e.g. ``"eco:0.3"``.
        dt_s: the simulation step, s (``cruise`` reaches its speed in one step).
    """

    spec: str
    dt_s: float = 0.5

    def __post_init__(self) -> None:
        _parts(self.spec)  # raises ValueError on a bad spec

    @property
    def observer(self) -> str:
        """The observer it reads: ``"lanes"`` with a lane rule, else ``"rich"``."""
        return "rich" if _parts(self.spec)[1] is None else "lanes"

    def act(self, obs: jax.Array) -> jax.Array:
        """The acceleration command of every slot, float (M,) m/s^2 (NaN: none).

        Args:
            obs: float (M, D) rows of `observer` (the rich 17 first).
        """
        speed, _ = _parts(self.spec)
        if speed is None:
            return jnp.full(obs.shape[:1], NO_COMMAND, obs.dtype)
        return RULES[speed[0]](obs, speed[1], self.dt_s)

    def action(self, obs: jax.Array) -> jax.Array:
        """The environment's action, float (M, 2): `act` and the lane column
        (`jaxround.envs.scripted_lanes`; NaN, no request, without a lane rule)."""
        accel = self.act(obs)
        _, lane = _parts(self.spec)
        no_request = jnp.full_like(accel, jnp.nan)
        change = no_request if lane is None else lane_choice(obs, *lane)
        return jnp.stack([accel, change.astype(accel.dtype)], axis=-1)


def controller_from_spec(spec: str, dt_s: float = 0.5) -> ScriptedController:
    """The scripted controller of `spec`.

    Raises:
        ValueError: the spec names no controller, lacks or has a bad number.
    """
    return ScriptedController(spec=spec, dt_s=dt_s)


def rule_and_value(spec: str) -> tuple[int, float]:
    """The index of the spec's rule in `RULES` and its value, for
    `scripted_command` (raises as `controller_from_spec`, and for a spec
    with a lane rule)."""
    speed, lane = _parts(spec)
    if speed is None or lane is not None:
        raise ValueError(f"controller spec {spec!r}: a speed rule alone is needed here")
    name, value = speed
    return list(RULES).index(name), value


def scripted_command(
    obs: jax.Array, rule: jax.Array, value: jax.Array, dt_s: float
) -> jax.Array:
    """The command of the rule with index `rule` (traced: one compiled program
    serves every controller of a batch), float (M,).

    Args:
        obs: float (M, 17) rich observation rows.
        rule: int, index into `RULES` (`rule_and_value`).
        value: float, the rule's value.
        dt_s: the simulation step, s.
    """
    branches = [
        lambda o, x, fn=fn: fn(o, x, dt_s).astype(o.dtype) for fn in RULES.values()
    ]
    return jax.lax.switch(rule, branches, obs, jnp.asarray(value, obs.dtype))


def is_scripted_spec(spec: str) -> bool:
    """Whether `spec` names a scripted controller (rather than, say, a file)."""
    return spec.split("+", 1)[0].split(":", 1)[0] in {*RULES, *LANE_RULES}


# ---------------------------------------------------------------------- rules


def constant_accel(obs: jax.Array, accel: float, dt_s: float) -> jax.Array:
    """``accel:A``: the same command A everywhere, float (M,)."""
    del dt_s
    return jnp.full(obs.shape[0], accel, obs.dtype)


def cruise(obs: jax.Array, target_speed: float, dt_s: float) -> jax.Array:
    """``cruise:V``: ``(V - v) / dt``, float (M,)."""
    return (target_speed - obs[:, OWN_SPEED] * SPEED_SCALE) / dt_s


def eco_approach(obs: jax.Array, coast_decel: float, dt_s: float) -> jax.Array:
    """``eco:B``: brake evenly to a certain stop once that takes B m/s^2, float (M,)."""
    del dt_s
    v = obs[:, OWN_SPEED] * SPEED_SCALE
    gap = obs[:, LEADER_GAP] * DISTANCE_SCALE
    v_lead = v + obs[:, LEADER_REL_SPEED] * SPEED_SCALE
    standing_leader = (obs[:, LEADER_GAP] < 1.0) & (v_lead < STANDING_SPEED)
    to_queue = jnp.where(standing_leader, gap - STOP_GAP_M, jnp.inf)
    line = obs[:, TO_YIELD_LINE] * DISTANCE_SCALE - LINE_MARGIN_M
    to_line = jnp.where(entry_taken(obs), line, jnp.inf)
    stop_in = jnp.maximum(jnp.minimum(to_queue, to_line), 0.1)  # (M,)
    needed = v * v / (2.0 * stop_in)  # 0 where no stop is certain
    return jnp.where(needed >= coast_decel, -needed, NO_COMMAND)


def timed_approach(obs: jax.Array, headway_s: float, dt_s: float) -> jax.Array:
    """``timed:H``: reach the yield line H s after the ring vehicle reaches
    the entry, slowing evenly, float (M,)."""
    del dt_s
    v = obs[:, OWN_SPEED] * SPEED_SCALE
    dist = jnp.maximum(obs[:, TO_YIELD_LINE] * DISTANCE_SCALE, 0.1)
    arrive_in = obs[:, RING_ARRIVAL] * RING_HORIZON_S + headway_s
    v_end = jnp.maximum(2.0 * dist / arrive_in - v, 0.0)
    # v_end^2 = v^2 + 2 a d: the even deceleration that arrives at v_end
    accel = (v_end * v_end - v * v) / (2.0 * dist)
    slow_down = entry_taken(obs) & (accel < 0.0)
    return jnp.where(slow_down, accel, NO_COMMAND)


def entry_taken(obs: jax.Array) -> jax.Array:
    """bool (M,): on the approach, and the ring vehicle seen will be at the
    entry when this vehicle reaches the yield line at its speed: neither
    gone by then nor far enough behind to let it enter first."""
    v = obs[:, OWN_SPEED] * SPEED_SCALE
    to_line = obs[:, TO_YIELD_LINE] * DISTANCE_SCALE
    ring = obs[:, RING_ARRIVAL]
    t_ring = ring * RING_HORIZON_S
    t_self = to_line / jnp.maximum(v, 0.1)
    coming = ring < 1.0  # 1 reads "nothing within the horizon"
    return (
        (to_line > 0.0)
        & coming
        & (t_ring > t_self - RING_CLEAR_S)
        & (t_ring < t_self + GO_FIRST_S)
    )


#: name -> rule(obs, value, dt_s).
RULES: dict[str, Callable[[jax.Array, float, float], jax.Array]] = {
    "accel": constant_accel,
    "cruise": cruise,
    "eco": eco_approach,
    "timed": timed_approach,
}
#: Default value of each rule; None: the spec must give one.
DEFAULTS: dict[str, float | None] = {
    "accel": None,
    "cruise": None,
    "eco": ECO_DECEL,
    "timed": RING_CLEAR_S,
}
#: Smallest value each rule accepts (inclusive), None: any finite number.
LOWEST: dict[str, float | None] = {
    "accel": None,
    "cruise": 0.0,
    "eco": 0.0,
    "timed": 0.5,
}


def _parts(spec: str) -> tuple[tuple[str, float] | None, tuple[str, float] | None]:
    """(speed rule, lane rule) of a spec, each (name, value) or None; checked."""
    if not isinstance(spec, str):
        raise ValueError(f"controller spec {spec!r}: expected a string")
    first, plus, lane = spec.partition("+")
    if not plus and first.split(":", 1)[0] in LANE_RULES:
        return None, parse_lane_rule(spec, first)
    speed = _parse(first if plus else spec, spec)
    return speed, parse_lane_rule(spec, lane) if plus else None


def _parse(text: str, spec: str | None = None) -> tuple[str, float]:
    """(rule name, value) of the speed rule ``text`` of ``spec``, checked."""
    spec = text if spec is None else spec
    if not isinstance(text, str):
        raise ValueError(f"controller spec {spec!r}: expected a string")
    name, sep, text = text.partition(":")
    if name not in RULES:
        raise ValueError(
            f"controller spec {spec!r}: unknown controller {name!r}; expected "
            "accel:A, cruise:V, eco[:B] or timed[:H], then +inner, +outer or "
            "+gap:X, or a lane rule alone"
        )
    if not sep:
        value = DEFAULTS[name]
        if value is None:
            raise ValueError(
                f"controller spec {spec!r}: {name} needs a value, {name}:X"
            )
        return name, value
    try:
        value = float(text)
    except ValueError:
        raise ValueError(
            f"controller spec {spec!r}: {text!r} is not a number"
        ) from None
    if not math.isfinite(value):
        raise ValueError(f"controller spec {spec!r}: {text!r} is not finite")
    lowest = LOWEST[name]
    if lowest is not None and value < lowest:
        raise ValueError(f"controller spec {spec!r}: {name} needs a value >= {lowest}")
    return name, value
