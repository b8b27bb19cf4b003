"""SUMO's lane-change action bits (`LaneChangeAction`, SUMOXMLDefinitions.h).

A vehicle's LC2013 state (`myOwnState`) and the lane-change output's
``reason`` are OR-ed sets of these bits.
"""

from __future__ import annotations

STAY = 1
LEFT = 2
RIGHT = 4
STRATEGIC = 8
COOPERATIVE = 16
SPEEDGAIN = 32
KEEPRIGHT = 64
TRACI = 128
URGENT = 256
BLOCKED_BY_LEFT_LEADER = 512
BLOCKED_BY_LEFT_FOLLOWER = 1024
BLOCKED_BY_RIGHT_LEADER = 2048
BLOCKED_BY_RIGHT_FOLLOWER = 4096
OVERLAPPING = 8192
INSUFFICIENT_SPACE = 16384
AMBLOCKINGLEADER = 1 << 16
AMBLOCKINGFOLLOWER = 1 << 17
MRIGHT = 1 << 18
MLEFT = 1 << 19
AMBLOCKINGFOLLOWER_DONTBRAKE = 1 << 21
AMBACKBLOCKER = 1 << 26
AMBACKBLOCKER_STANDING = 1 << 27
INSUFFICIENT_SPEED = 1 << 28

WANTS_LANECHANGE = LEFT | RIGHT
BLOCKED_BY_LEADER = BLOCKED_BY_LEFT_LEADER | BLOCKED_BY_RIGHT_LEADER
BLOCKED_BY_FOLLOWER = BLOCKED_BY_LEFT_FOLLOWER | BLOCKED_BY_RIGHT_FOLLOWER
BLOCKED = BLOCKED_BY_LEADER | BLOCKED_BY_FOLLOWER | INSUFFICIENT_SPACE
#: SUMO's own LCA_BLOCKED, with LCA_INSUFFICIENT_SPEED: what SUMO 1.28 sets on
#: a change held back at an entry (`jaxround.lanes.entry_hold`)
HELD = BLOCKED | INSUFFICIENT_SPEED
#: the bits a vehicle keeps from what others told it (`ret = myOwnState & 0xffff0000`)
MESSAGE_BITS = 0x7FFF0000

_REASONS = (
    (STRATEGIC, "strategic"), (COOPERATIVE, "cooperative"), (SPEEDGAIN, "speedGain"),
    (KEEPRIGHT, "keepRight"), (TRACI, "traci"), (URGENT, "urgent"),
)  # fmt: skip


def reason(state: int) -> str:
    """The lane-change output's ``reason`` of a state, e.g. "strategic|urgent"."""
    return "|".join(name for bit, name in _REASONS if int(state) & bit)
