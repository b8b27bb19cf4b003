"""The conflict of two crossing internal lanes, as SUMO's
``MSLink::setRequestInformation`` measures it (`jaxround.core.crossing_tables`)."""

import numpy as np
import pytest

from jaxround.core.crossing_tables import CrossingArrays, crossing_conflicts


def test_two_lanes_at_right_angles_conflict_over_the_foes_width():
    # lane 0 west to east along y = 0, lane 1 south to north along x = 6
    shapes = (np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[6.0, -4.0], [6.0, 8.0]]))
    lengths, widths = np.array([10.0, 12.0]), np.array([3.2, 3.0])
    c = crossing_conflicts([(0, 1)], shapes, lengths, widths)
    # sin 90 = 1: the area is as long as the foe is wide, centred on the crossing
    assert c.size.tolist() == pytest.approx([3.0, 3.2])
    assert c.behind[0] == pytest.approx(10.0 - (6.0 - 1.5))
    assert c.behind[1] == pytest.approx(12.0 - (4.0 - 1.6))
    assert c.foe_behind[0] == pytest.approx(c.behind[1])
    assert c.foe_size[1] == pytest.approx(c.size[0])
    assert c.minor.tolist() == [True, False]
    assert c.lane.tolist() == [0, 1] and c.foe.tolist() == [1, 0]


def test_a_shallow_crossing_has_a_longer_area_and_lanes_apart_none():
    shapes = (
        np.array([[0.0, 0.0], [40.0, 0.0]]),
        np.array([[0.0, -4.0], [40.0, 4.0]]),  # about 11.3 degrees
        np.array([[0.0, 5.0], [40.0, 5.0]]),  # parallel to lane 0
    )
    lengths, widths = np.array([40.0, 40.8, 40.0]), np.full(3, 3.2)
    c = crossing_conflicts([(0, 1)], shapes, lengths, widths)
    sine = max(np.sin(np.arctan2(8.0, 40.0)), 0.2)  # SUMO's floor of 0.2
    assert c.size[0] == pytest.approx(3.2 * (2 / sine - 1))  # 28.8 m
    short = crossing_conflicts([(0, 1)], shapes, np.array([20.0, 20.4, 20.0]), widths)
    assert short.size[0] == pytest.approx(20.0)  # at most the lane's length
    assert crossing_conflicts([(0, 2)], shapes, lengths, widths) is None


def test_routes_find_the_next_crossing_lane_at_or_after_each_lane():
    shapes = (np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[6.0, -4.0], [6.0, 8.0]]))
    c = crossing_conflicts([(0, 1)], shapes, np.array([10.0, 12.0]), np.full(2, 3.2))
    route_lanes = np.array([[5, 0, 7, -1], [5, 6, 1, 7], [5, 6, 7, -1]])
    arrays = CrossingArrays.build(c, route_lanes)
    assert np.asarray(arrays.next_row).tolist() == [
        [0, 0, -1, -1],
        [1, 1, 1, -1],
        [-1, -1, -1, -1],
    ]
    assert np.asarray(arrays.next_index)[1].tolist() == [2, 2, 2, 0]
