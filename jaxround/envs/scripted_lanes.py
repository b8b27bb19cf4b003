"""Scripted lane choices for AVs on two-lane roads, on the ``"lanes"``
observation (`jaxround.envs.lane_view`).

Each rule gives the lane column of an AV's action (`jaxround.envs.lane_view`:
+1 ask for the lane to the left, -1 to the right, 0 hold the lane, NaN ask
nothing). A lane counts only where its lane path goes on for at least
`DISTANCE_SCALE` (50 m) from beside the AV (its ``room`` column is 1), so
no rule sends an AV onto a lane it must leave at once (the inner ring lane
just before the AV's exit, say). Where a rule asks for no change the AV
holds its lane while its own lane path goes on for 50 m; closer to that
path's end it asks nothing, and LC2013 takes it to the lane of its exit.

- ``inner``: ask for the lane to the left wherever it counts.
- ``outer``: ask for the lane to the right wherever it counts.
- ``gap:X``: ask for the lane beside whose gap to the next vehicle ahead is
  more than X m longer than the gap on the AV's own lane (gaps seen up to
  50 m; where lanes on both sides count, the longer gap, left on a tie).

A lane rule is combined with a speed rule as ``SPEED+LANE``, e.g.
``eco+gap:5`` (`jaxround.envs.scripted`); alone, the AV gets no speed
command. On one-lane roads no lane counts and the rules ask nothing.

Shapes: M slots.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from jaxround.envs.lane_view import (
    GAP_LEFT,
    GAP_OWN,
    GAP_RIGHT,
    HOLD_LANE,
    LEFT_LANE,
    RIGHT_LANE,
    ROOM_LEFT,
    ROOM_OWN,
    ROOM_RIGHT,
)
from jaxround.envs.observe import DISTANCE_SCALE

#: Lane rules by name, and whether each needs a value (m).
LANE_RULES = {"inner": False, "outer": False, "gap": True}


def parse_lane_rule(spec: str, text: str) -> tuple[str, float]:
    """(name, value) of the lane part ``text`` of controller spec ``spec``.

    Raises:
        ValueError: not a lane rule, or a missing, extra or bad value.
    """
    name, sep, number = text.partition(":")
    if name not in LANE_RULES:
        raise ValueError(
            f"controller spec {spec!r}: unknown lane rule {name!r}; expected "
            "inner, outer or gap:X"
        )
    if LANE_RULES[name] != bool(sep):
        need = f"{name}:X (m)" if LANE_RULES[name] else f"{name}, without a value"
        raise ValueError(f"controller spec {spec!r}: expected {need}")
    if not sep:
        return name, 0.0
    try:
        value = float(number)
    except ValueError:
        raise ValueError(
            f"controller spec {spec!r}: {number!r} is not a number"
        ) from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"controller spec {spec!r}: {name} needs a value >= 0 (m)")
    return name, value


def lane_choice(obs: jax.Array, name: str, margin_m: float) -> jax.Array:
    """The lane column of every slot, float (M,): -1, 0, 1 or NaN.

    Args:
        obs: float (M, 24) ``"lanes"`` observation rows.
        name: a rule of `LANE_RULES`.
        margin_m: the ``gap`` rule's X (m).
    """
    left_counts = obs[:, ROOM_LEFT] >= 1.0
    right_counts = obs[:, ROOM_RIGHT] >= 1.0
    if name == "inner":
        left, right = left_counts, jnp.zeros_like(left_counts)
    elif name == "outer":
        left, right = jnp.zeros_like(right_counts), right_counts
    else:
        own = obs[:, GAP_OWN] * DISTANCE_SCALE + margin_m
        gap_left = obs[:, GAP_LEFT] * DISTANCE_SCALE
        gap_right = obs[:, GAP_RIGHT] * DISTANCE_SCALE
        left = left_counts & (gap_left > own)
        left = left & ~(right_counts & (gap_right > gap_left))
        right = right_counts & (gap_right > own) & ~left
    hold = obs[:, ROOM_OWN] >= 1.0
    column = jnp.where(hold, HOLD_LANE, jnp.nan)
    column = jnp.where(left, LEFT_LANE, jnp.where(right, RIGHT_LANE, column))
    return column.astype(obs.dtype)
