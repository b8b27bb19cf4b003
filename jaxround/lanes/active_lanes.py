"""The order in which SUMO's edges take their lane-change turns.

SUMO's changer runs edge by edge (`MSEdgeControl::changeLanes`, SUMO's
``src/microsim/MSEdgeControl.cpp``), along its list of active lanes
(``myActiveLanes``): an edge's turn comes at the first of its lanes in that
list. A lane of an edge with a changer joins the list at its **front**
whenever it becomes occupied again, and leaves it when it holds no
vehicle, so the edge whose lane was occupied last goes first:

- after the move (`executeMovements`), a lane none of whose vehicles
  stayed on it leaves the list, and every lane that then receives vehicles
  and is not in it joins, in the order of the lanes' ids as strings
  (``ComparatorIdLess``), each at the front;
- after the lane changes, a lane a change made occupied joins, in the
  order the edges took their turns (lanes by index within an edge);
- a lane a vehicle was inserted into joins at the start of the next step
  (`patchActiveLanes`), in the order of the lanes' numerical ids (their
  order in the network file).

Each lane's place is kept as a stamp (int32 (L,), 0: not in the list): a
lane joining gets a stamp above every other, so the larger stamp is the
nearer the front. The order matters where a vehicle's turn reads another
edge's lanes as the turns before it left them: the roundabout bonus's
occupancies (`jaxround.lanes.ring_neighbours.roundabout_bonus`) and
neighbours found on another edge.

Shapes: L lanes, M vehicle slots.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.lanes.ring_changer import RingArrays, locate


class TurnOrder(NamedTuple):
    """A network's static tables for the edges' turn order, (L,) each:
    each lane's rank among the lane ids as strings (``id_rank``) and in the
    network file (``file_rank``, SUMO's numerical ids), ``same_edge``
    bool (L, L), and the changer's arrays."""

    id_rank: jax.Array
    file_rank: jax.Array
    same_edge: jax.Array
    arrays: RingArrays

    @classmethod
    def of(
        cls, net_file: str | Path, lane_ids: Sequence[str], arrays: RingArrays
    ) -> TurnOrder:
        """The tables of the lanes ``lane_ids`` of ``net_file``."""
        in_file = [lane.get("id") for lane in ET.parse(net_file).getroot().iter("lane")]
        position = {lane_id: k for k, lane_id in enumerate(in_file)}
        by_name = {lane_id: k for k, lane_id in enumerate(sorted(lane_ids))}
        edge = np.asarray(arrays.lane_order)
        return cls(
            id_rank=jnp.asarray([by_name[x] for x in lane_ids], jnp.int32),
            file_rank=jnp.asarray([position[x] for x in lane_ids], jnp.int32),
            same_edge=jnp.asarray(edge[:, None] == edge[None, :]),
            arrays=arrays,
        )

    def before_changes(
        self,
        stamp: jax.Array,
        *,
        path: jax.Array,
        pos: jax.Array,
        speed: jax.Array,
        active: jax.Array,
        dt: float,
    ) -> tuple[jax.Array, RingArrays]:
        """(stamps, arrays): the stamps when the changer starts (`after_move`)
        and the changer's arrays with this step's `edge_order`, from the
        vehicles after the move ((M,) each)."""
        stamp = after_move(
            self.arrays, stamp, path, pos, speed, active, dt,
            id_rank=self.id_rank, file_rank=self.file_rank,
        )  # fmt: skip
        order = edge_order(stamp, self.same_edge)
        return stamp, self.arrays._replace(lane_order=order)


def join(stamp: jax.Array, joins: jax.Array, push_rank: jax.Array) -> jax.Array:
    """The stamps after the lanes ``joins`` (bool (L,)) joined the front one
    by one in the order of ``push_rank`` (int (L,), smaller first): the last
    one pushed is the front."""
    before = jnp.sum(joins[None, :] & (push_rank[None, :] < push_rank[:, None]), axis=1)
    return jnp.where(joins, jnp.max(stamp) + 1 + before, stamp).astype(jnp.int32)


def lane_counts(net: RingArrays, path: jax.Array, pos: jax.Array, active: jax.Array):
    """(lane, count): each slot's lane (M,) and each lane's vehicles (L,),
    by the lane of the front (SUMO's ``getVehicleNumber``)."""
    _, lane, _ = locate(net, path, pos)
    count = jnp.zeros(net.lane_length.shape[0], jnp.int32).at[lane].add(active)
    return lane, count


def after_move(
    net: RingArrays,
    stamp: jax.Array,
    path: jax.Array,
    pos: jax.Array,
    speed: jax.Array,
    active: jax.Array,
    dt: float,
    *,
    id_rank: jax.Array,
    file_rank: jax.Array,
) -> jax.Array:
    """The stamps when the changer starts, from the vehicles after the move
    (they were at ``pos - speed * dt`` on the same paths before it).

    First the lanes insertions occupied at the end of the last step join
    (``file_rank``: numerical-id order); then the move: a lane no vehicle
    stayed on leaves, a lane with vehicles and no stamp joins (``id_rank``:
    string-id order)."""
    lane_now, count_now = lane_counts(net, path, pos, active)
    lane_before, count_before = lane_counts(net, path, pos - speed * dt, active)
    stamp = join(stamp, (count_before > 0) & (stamp == 0), file_rank)
    stayed = active & (lane_before == lane_now)
    kept = jnp.zeros_like(count_now).at[lane_now].add(stayed) > 0
    stamp = jnp.where(kept, stamp, 0)
    return join(stamp, (count_now > 0) & (stamp == 0), id_rank)


def edge_order(stamp: jax.Array, same_edge: jax.Array) -> jax.Array:
    """int (L,): each lane's edge's place in the changer's loop (0 first),
    the `RingArrays.lane_order` of this step: edges by their frontmost lane's
    stamp, largest first (``same_edge``: bool (L, L), two lanes of one edge)."""
    key = jnp.max(jnp.where(same_edge, stamp[None, :], 0), axis=1)
    ahead = (key[None, :] > key[:, None]) & ~same_edge
    first_of_edge = jnp.argmax(same_edge, axis=1) == jnp.arange(key.shape[0])
    return jnp.sum(ahead & first_of_edge[None, :], axis=1).astype(jnp.int32)


def after_changes(
    net: RingArrays,
    stamp: jax.Array,
    order: jax.Array,
    lane: jax.Array,
    active: jax.Array,
) -> jax.Array:
    """The stamps after the lane changes, from each slot's lane after them
    (M,): a lane with vehicles and no stamp joins, in the edges' turn order
    (``order``, `edge_order`), lanes by index within an edge."""
    count = jnp.zeros(net.lane_length.shape[0], jnp.int32).at[lane].add(active)
    push_rank = order * 4 + net.lane_index
    return join(stamp, (count > 0) & (stamp == 0), push_rank)
