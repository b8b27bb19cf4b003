"""The lanes of each route before each merge, as index tables: minima over
"every lane of the look-ahead before the merge at leg g" without a
(M, K, G) array.

SUMO's planMoveInternal walks the lanes ahead in route order, so "the lanes
before the merge" is always a prefix of a route's lanes, and "the lane that
ends (or starts) at the merge" is one lane. The look-ahead
(`jaxround.core.right_of_way.look_ahead`) asks five such questions of every
vehicle; each was a masked minimum over an (M, K, G) array. Here each is one
static (R, G) table per network, and the minimum over a prefix is a running
minimum along the lanes, (M, K), read at the table's index, (M, G): the same
numbers bit for bit (a minimum is exact).

Shapes: R routes, K lanes per route, G legs (one merge each), M vehicles.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.geometry import NetArrays

#: Positions closer than this (m) are the same point (as the look-ahead's tests).
SAME_POINT_M = 1e-3


class MergePrefixes(NamedTuple):
    """Per route r and leg g, int (R, G) each (static numpy arrays):

    Attributes:
        starts_before: lanes whose start lies before the merge point.
        ends_early: lanes that end before the lane leading into the merge.
        starts_clearly_before: lanes that start more than `SAME_POINT_M`
            before the merge point.
        ends_at: the lane that ends at the merge point (-1: none).
        starts_at: the lane that starts at the merge point (-1: none).
    """

    starts_before: np.ndarray
    ends_early: np.ndarray
    starts_clearly_before: np.ndarray
    ends_at: np.ndarray
    starts_at: np.ndarray


def _prefix_length(mask: np.ndarray, what: str) -> np.ndarray:
    """The length of the prefix `mask` (R, K, G) is true on, (R, G); raises
    if a mask is not a prefix of the lanes (a network this module does not
    describe)."""
    count = mask.sum(axis=1)
    prefix = np.arange(mask.shape[1])[None, :, None] < count[:, None, :]
    if not np.array_equal(mask, prefix):
        raise ValueError(f"network: the lanes {what} are not a prefix of a route")
    return count.astype(np.int32)


def _single_lane(mask: np.ndarray, what: str) -> np.ndarray:
    """The one lane `mask` (R, K, G) is true on, (R, G) (-1: none)."""
    if np.any(mask.sum(axis=1) > 1):
        raise ValueError(f"network: more than one lane {what}")
    return np.where(mask.any(axis=1), mask.argmax(axis=1), -1).astype(np.int32)


def merge_prefixes(net: NetArrays) -> MergePrefixes:
    """The tables of a network, from the same float32 numbers the look-ahead
    compares (so that the tests they replace give the same lanes)."""
    f = np.float32
    starts = np.asarray(net.route_lane_start, f)[:, :, None]  # (R, K, 1), inf pad
    lanes = np.maximum(np.asarray(net.route_lanes), 0)
    ends = (starts[:, :, 0] + np.asarray(net.lane_length, f)[lanes])[:, :, None]
    conflict = np.asarray(net.conflict_offset, f)[:, None, :]  # (R, 1, G)
    prev_length = np.asarray(net.prev_lane_length, f)[:, None, :]
    eps = f(SAME_POINT_M)
    with np.errstate(invalid="ignore"):  # nan: the route does not pass leg g
        return MergePrefixes(
            starts_before=_prefix_length(starts < conflict, "before a merge"),
            ends_early=_prefix_length(
                ends < conflict - prev_length + eps, "ending before a merge's lane"
            ),
            starts_clearly_before=_prefix_length(
                starts < conflict - eps, "starting before a merge"
            ),
            ends_at=_single_lane(np.abs(ends - conflict) < eps, "ends at a merge"),
            starts_at=_single_lane(
                np.abs(starts - conflict) < eps, "starts at a merge"
            ),
        )


def prefix_min(values: jax.Array, length: jax.Array) -> jax.Array:
    """``min(values[i, :length[i, g]])``, float (M, G) (inf for an empty
    prefix), from `values` (M, K) and `length` int (M, G)."""
    running = jax.lax.cummin(values, axis=1)  # (M, K)
    padded = jnp.concatenate([jnp.full_like(values[:, :1], jnp.inf), running], 1)
    return jnp.take_along_axis(padded, length, axis=1)


def at_lane(values: jax.Array, lane: jax.Array) -> jax.Array:
    """``values[i, lane[i, g]]``, float (M, G) (inf where `lane` is -1), from
    `values` (M, K) and `lane` int (M, G)."""
    picked = jnp.take_along_axis(values, jnp.maximum(lane, 0), axis=1)
    return jnp.where(lane >= 0, picked, jnp.inf)
