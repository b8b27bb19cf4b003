"""Internal lanes that cross inside a junction, as SUMO measures the crossing.

A two-lane roundabout's left entry lane joins the inner ring lane across the
outer ring lane going on: the two internal lanes cross (they do not merge).
SUMO keeps, for the exit link of every internal lane, a conflict per foe
lane (``MSLink::myConflicts``, built by ``MSLink::setRequestInformation``):
where on the lane the conflict area begins, counted back from the lane's
end (``lengthBehindCrossing``), and how long the area is (``conflictSize``:
the foe lane's width, times ``2 / max(sin(angle), 0.2) - 1`` for the angle
between the two centre lines where they cross). `crossing_conflicts` computes
both from the net's shapes; `CrossingArrays` holds them for the step, with
where each route meets them (`jaxround.core.crossing_leaders` reads them).

Shapes: X crossing rows (a lane and one foe; each crossing twice, once from
each side), R routes, K lanes per route.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

#: SUMO's smallest sine in the conflict's width factor (``MSLink.cpp``).
MIN_SINE = 0.2


@dataclass(frozen=True)
class CrossingConflicts:
    """The crossings of a network, one row per (lane, foe lane), numpy.

    Attributes:
        lane: int (X,) the internal lane whose exit link has the conflict.
        foe: int (X,) the internal lane it crosses.
        behind: float (X,) the lane's length behind the conflict area.
        size: float (X,) the conflict area's length along the lane.
        foe_behind: float (X,) the foe lane's length behind the area.
        foe_size: float (X,) the area's length along the foe lane.
        minor: bool (X,) the lane's link yields to the foe's (an entry's link
            against the ring's: SUMO's junction logic, ``MSVehicle::isLeader``).
    """

    lane: np.ndarray
    foe: np.ndarray
    behind: np.ndarray
    size: np.ndarray
    foe_behind: np.ndarray
    foe_size: np.ndarray
    minor: np.ndarray


def _arc_lengths(shape: np.ndarray) -> np.ndarray:
    """Distance along polyline `shape` (n, 2) to each of its points, (n,)."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(shape, axis=0).T))])


def _intersections(
    a: np.ndarray, b: np.ndarray
) -> list[tuple[float, float, float, float]]:
    """Where polylines a (n, 2) and b cross: (offset along a, offset along b,
    a's heading there, b's heading there), headings in degrees. SUMO's
    ``PositionVector::intersectsAtLengths2D`` (both ways)."""
    hits = []
    len_a, len_b = _arc_lengths(a), _arc_lengths(b)
    for i in range(len(a) - 1):
        p, r = a[i], a[i + 1] - a[i]
        for j in range(len(b) - 1):
            q, s = b[j], b[j + 1] - b[j]
            denom = r[0] * s[1] - r[1] * s[0]
            if abs(denom) < 1e-12:
                continue
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
            u = ((q - p)[0] * r[1] - (q - p)[1] * r[0]) / denom
            if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
                hits.append(
                    (
                        len_a[i] + t * (len_a[i + 1] - len_a[i]),
                        len_b[j] + u * (len_b[j + 1] - len_b[j]),
                        float(np.degrees(np.arctan2(r[1], r[0]))),
                        float(np.degrees(np.arctan2(s[1], s[0]))),
                    )
                )
    return hits


def conflict_on(
    shape: np.ndarray, length: float, at: float, angle_deg: float, foe_width: float
) -> tuple[float, float]:
    """(lengthBehindCrossing, conflictSize) of a lane whose centre line
    crosses a foe's `at` metres along its shape, at `angle_deg` between the
    two (``MSLink::setRequestInformation``, the crossing case)."""
    sine = max(abs(np.sin(np.radians(angle_deg))), MIN_SINE)
    size = min(foe_width * (2.0 / sine - 1.0), length)
    geometric = max(0.0, at - size / 2)
    shape_length = float(_arc_lengths(shape)[-1])
    lane_pos = geometric * length / shape_length if shape_length > 0 else geometric
    return length - lane_pos, size


def crossing_conflicts(
    pairs: list[tuple[int, int]],
    shapes: tuple[np.ndarray, ...],
    lengths: np.ndarray,
    widths: np.ndarray,
) -> CrossingConflicts | None:
    """Both sides of each crossing of (minor lane, major lane) in `pairs`
    (lane indices into `shapes`, `lengths`, `widths`); None if none cross."""
    rows = []
    for minor, major in pairs:
        hits = _intersections(shapes[minor], shapes[major])
        if not hits:
            continue
        at_minor = max(h[0] for h in hits)  # SUMO sorts each side, takes the last
        at_major = max(h[1] for h in hits)
        last = max(hits, key=lambda h: h[0])
        angle = abs((last[2] - last[3] + 180.0) % 360.0 - 180.0)
        behind_a, size_a = conflict_on(
            shapes[minor], float(lengths[minor]), at_minor, angle, float(widths[major])
        )
        behind_b, size_b = conflict_on(
            shapes[major], float(lengths[major]), at_major, angle, float(widths[minor])
        )
        rows.append((minor, major, behind_a, size_a, behind_b, size_b, True))
        rows.append((major, minor, behind_b, size_b, behind_a, size_a, False))
    if not rows:
        return None
    cols = list(zip(*rows, strict=True))
    return CrossingConflicts(
        lane=np.array(cols[0], np.int32),
        foe=np.array(cols[1], np.int32),
        behind=np.array(cols[2]),
        size=np.array(cols[3]),
        foe_behind=np.array(cols[4]),
        foe_size=np.array(cols[5]),
        minor=np.array(cols[6], bool),
    )


@dataclass(frozen=True)
class CrossingArrays:
    """`CrossingConflicts` as device arrays, with where routes meet them.

    Attributes:
        lane, foe, behind, size, foe_behind, foe_size, minor: (X,) as in
            `CrossingConflicts`.
        next_row: int (R, K) the row of the first crossing lane at or after
            route lane k (-1: none ahead).
        next_index: int (R, K) that lane's route index (0 where none).
    """

    lane: jax.Array
    foe: jax.Array
    behind: jax.Array
    size: jax.Array
    foe_behind: jax.Array
    foe_size: jax.Array
    minor: jax.Array
    next_row: jax.Array
    next_index: jax.Array

    @classmethod
    def build(
        cls, conflicts: CrossingConflicts, route_lanes: np.ndarray
    ) -> CrossingArrays:
        row_of = {int(lane): x for x, lane in enumerate(conflicts.lane)}
        r_n, k_n = route_lanes.shape
        next_row = -np.ones((r_n, k_n), np.int32)
        next_index = np.zeros((r_n, k_n), np.int32)
        for r in range(r_n):
            row, index = -1, 0
            for k in range(k_n - 1, -1, -1):
                if int(route_lanes[r, k]) in row_of:
                    row, index = row_of[int(route_lanes[r, k])], k
                next_row[r, k], next_index[r, k] = row, index
        f = jnp.float32
        return cls(
            lane=jnp.asarray(conflicts.lane),
            foe=jnp.asarray(conflicts.foe),
            behind=jnp.asarray(conflicts.behind, f),
            size=jnp.asarray(conflicts.size, f),
            foe_behind=jnp.asarray(conflicts.foe_behind, f),
            foe_size=jnp.asarray(conflicts.foe_size, f),
            minor=jnp.asarray(conflicts.minor),
            next_row=jnp.asarray(next_row),
            next_index=jnp.asarray(next_index),
        )
