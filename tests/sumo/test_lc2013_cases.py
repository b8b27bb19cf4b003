"""SUMO's lane-change model LC2013 on four hand-checked cases (SUMO 1.28).

Each case is a straight two-lane road of a few hundred metres, one to two
vehicles of the IDM vType (speedDev 0, so every driver is the same), a step
of 1 s and a few seconds of simulation. Each test predicts from the model's
formulas (docs/lc2013-map.md) what SUMO must do and checks it against SUMO's
lane-change output and the model state that libsumo exposes
(`vehicle.getParameter(id, "laneChangeModel.<key>")`).

Times are those of SUMO's outputs: the step in which the vehicle moved and
then changed (libsumo's clock reads one step later after `simulationStep`).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import sumolib

from jaxround.apps.lane_parity import V_MAX, two_lane_road
from jaxround.apps.lane_parity import run_sumo as run

pytestmark = pytest.mark.sumo

LENGTH, MIN_GAP, TAU = 5.0, 2.5, 1.0  # the default passenger vType
ACCEL, DECEL = 2.6, 4.5  # IDM's defaults in SUMO
THRESHOLD_RIGHT = 0.2 / 0.1  # myChangeProbThresholdRight at lcSpeedGainRight 0.1

# LaneChangeAction bits (SUMO's SUMOXMLDefinitions.h)
LCA_LEFT, LCA_STRATEGIC, LCA_URGENT = 2, 8, 256
LCA_BLOCKED_BY_LEFT_FOLLOWER = 1024


def lc_state(vid: str, key: str) -> float:
    """A number of the vehicle's LC2013 state (`MSLCM_LC2013::getParameter`)."""
    import libsumo

    return float(libsumo.vehicle.getParameter(vid, f"laneChangeModel.{key}"))


def idm_secure_gap(v_follower: float, v_leader: float) -> float:
    """`MSCFModel_IDM::getSecureGap`: IDM's desired gap without minGap."""
    two_sqrt_ab = 2 * math.sqrt(ACCEL * DECEL)
    return max(
        0.0, v_follower * TAU + v_follower * (v_follower - v_leader) / two_sqrt_ab
    )


def brake_gap(v: float) -> float:
    """`MSCFModel::brakeGap` (Euler, dt 1 s): braking at decel, plus v * tau."""
    steps = int(v / DECEL)
    return steps * v - DECEL * steps * (steps + 1) / 2 + v * TAU


@pytest.mark.parametrize(("strategic", "lookahead_left"), [(1, 2), (0.5, 2), (1, 1)])
def test_strategic_change_before_the_lane_ends(
    tmp_path: Path, strategic: float, lookahead_left: float
) -> None:
    """A lone vehicle on the right lane, whose lane leads off its route,
    changes left (`MSLCM_LC2013::_wantsChange`, "urgent" branch) in the first
    step where the distance left on its lane falls below

        laDist = lookAheadSpeed * 10 * lcStrategic * lcLookaheadLeft
                 + 2 * (length + minGap)

    (LOOK_FORWARD 10 s; lcLookaheadLeft only for changes to the left), the
    look-ahead speed being the speed itself on a free road (it grows at once
    and decays by 0.9 per second). Not earlier: on an empty road the
    non-urgent strategic wish needs a speed gain it does not have."""
    net = two_lane_road(tmp_path, 1000.0, left_only=True)
    lane_length = sumolib.net.readNet(str(net)).getLane("e1_0").getLength()
    track: list[tuple[float, float]] = []

    def probe(t: int) -> None:
        import libsumo

        track.append(
            (libsumo.vehicle.getLanePosition("v"), libsumo.vehicle.getSpeed("v"))
        )

    lc = f'lcStrategic="{strategic}" lcLookaheadLeft="{lookahead_left}"'
    vehicle = (
        '<vehicle id="v" type="t" depart="0" departLane="0" departSpeed="max">'
        '<route edges="e1 e2"/></vehicle>'
    )
    (change,) = run(tmp_path, net, vehicle, 75, probe, lc=lc)
    assert change["reason"] == "strategic|urgent" and change["to"] == "e1_1"
    look_ahead, predicted = 0.0, None
    for t, (pos, v) in enumerate(track[1:], start=1):  # step 0 inserts it
        look_ahead = v if v > look_ahead else 0.9 * look_ahead + 0.1 * v
        la_dist = look_ahead * 10 * strategic * lookahead_left + 2 * (LENGTH + MIN_GAP)
        if lane_length - pos < la_dist:
            predicted = t
            break
    assert predicted is not None
    assert float(change["time"]) == predicted
    left = lane_length - float(change["pos"])
    assert 0 < left < 10 * V_MAX * strategic * lookahead_left + 15


def test_speed_gain_change_past_a_slow_leader(tmp_path: Path) -> None:
    """Behind a 5 m/s leader with the left lane free, the vehicle's
    speed-gain wish (`_wantsChange`, "ONLY FOR CHANGING TO THE LEFT")
    accumulates mySpeedGainProbability by the relative gain of the left lane
    each second and changes once it passes 0.2 / lcSpeedGain (speedGainLP,
    the ratio to that threshold, below 1 every step before). With
    lcSpeedGain 0 the threshold is out of reach and it stays behind. Past
    the leader it keeps right again, only once the leader (now its follower
    on the right lane) is more than its secure gap behind (`checkChange`)."""
    net = two_lane_road(tmp_path, 600.0, left_only=False)
    vehicles = (
        '<vehicle id="lead" type="slow" depart="0" departLane="0" departPos="60" '
        'departSpeed="5"><route edges="e1"/></vehicle>'
        '<vehicle id="v" type="t" depart="0" departLane="0" departSpeed="max">'
        '<route edges="e1"/></vehicle>'
    )
    ratios: list[float] = []

    def probe(t: int) -> None:
        ratios.append(lc_state("v", "speedGainLP"))

    changes = run(tmp_path, net, vehicles, 20, probe)
    first, back = changes
    assert (first["id"], first["reason"], first["dir"]) == ("v", "speedGain", "1")
    assert float(first["origLeaderSpeed"]) == 5.0
    t = int(float(first["time"]))
    before = ratios[1:t]  # step 0 inserts, step t changes and resets the state
    assert before and all(0 <= r <= 1 for r in before)
    # IDM brakes before LC2013 sees a gain: the wish is judged by the safe
    # speed behind the leader (`anticipateFollowSpeed`), not IDM's speed
    assert float(first["speed"]) < V_MAX - 1
    assert back["reason"] == "keepRight" and back["dir"] == "-1"
    assert float(back["followerGap"]) >= float(back["followerSecureGap"])
    assert float(back["time"]) > t

    lazy = run(tmp_path, net, vehicles, 20, lc='lcSpeedGain="0"')
    assert lazy == []


@pytest.mark.parametrize("length", [2000.0, 600.0])
def test_keep_right_after_its_probability_builds_up(
    tmp_path: Path, length: float
) -> None:
    """A lone vehicle on the left lane of a free road moves right
    (`_wantsChange`, "honor the obligation to keep right"): each second
    myKeepRightProbability falls by

        THRESHOLD_RIGHT * (min(T, fullSpeedGap / vMax) / T) / KEEP_RIGHT_TIME

    with T = 7 * max(1, v) (lcKeepRightAcceptanceTime unset), fullSpeedGap =
    neighDist - brakeGap(vMax) and KEEP_RIGHT_TIME 5 s; it changes in the
    first step where the probability times lcKeepRight is below -2.
    neighDist is the right lane's length from its start (`LaneQ::length`),
    so the rate does not change as the vehicle drives on: 0.4 a second on
    2 km (change after 6 s), 0.169 on 600 m (after 12 s)."""
    net = two_lane_road(tmp_path, length, left_only=False)
    lane_length = sumolib.net.readNet(str(net)).getLane("e1_0").getLength()
    ratios: list[float] = []

    def probe(t: int) -> None:
        ratios.append(lc_state("v", "keepRightP"))

    vehicle = (
        '<vehicle id="v" type="t" depart="0" departLane="1" departSpeed="max">'
        '<route edges="e1"/></vehicle>'
    )
    (change,) = run(tmp_path, net, vehicle, 16, probe)
    acceptance = 7 * V_MAX
    full_speed_s = min(acceptance, max(0.0, lane_length - brake_gap(V_MAX)) / V_MAX)
    rate = THRESHOLD_RIGHT * (full_speed_s / acceptance) / 5.0  # per second
    steps = math.floor(THRESHOLD_RIGHT / rate) + 1  # first k with k * rate > 2
    assert change["reason"] == "keepRight" and change["dir"] == "-1"
    assert float(change["time"]) == steps  # decisions from step 1 on
    for k in range(1, steps):
        assert ratios[k] == pytest.approx(k * rate / THRESHOLD_RIGHT, abs=1e-5)


def test_blocked_by_a_follower_on_the_target_lane(tmp_path: Path) -> None:
    """A vehicle at 8 m/s that must change left at once (160 m left, laDist
    175 m) has a follower at 13.89 m/s on the left lane 16.6 m behind
    (minus minGap): the change is refused while that gap is below the
    follower's secure gap (`MSLaneChanger::checkChange`: IDM's
    `getSecureGap`, v_f * tau + v_f * (v_f - v) / (2 sqrt(a b)), times
    1 / lcAssertive), marked LCA_BLOCKED_BY_LEFT_FOLLOWER. Being urgent it
    asks the follower to make room (`informFollower`, LCA_AMBLOCKINGFOLLOWER):
    the follower brakes, and the change follows in the next step, with the
    gap above the secure gap SUMO computes from the two speeds."""
    net = two_lane_road(tmp_path, 400.0, left_only=True)
    vehicles = (
        '<vehicle id="f" type="t" depart="0" departLane="1" departPos="210" '
        'departSpeed="13.89"><route edges="e1 e2"/></vehicle>'
        '<vehicle id="v" type="eight" depart="0" departLane="0" departPos="240" '
        'departSpeed="8"><route edges="e1 e2"/></vehicle>'
    )
    seen: list[tuple[int, float, float, float]] = []

    def probe(t: int) -> None:
        import libsumo

        vh = libsumo.vehicle
        if vh.getLaneIndex("v") == 0 and t > 0:
            gap = vh.getLanePosition("v") - LENGTH - vh.getLanePosition("f") - MIN_GAP
            state = vh.getLaneChangeState("v", 1)[0]
            seen.append((state, gap, vh.getSpeed("f"), vh.getSpeed("v")))

    (change,) = run(tmp_path, net, vehicles, 6, probe)
    assert seen, "the vehicle changed in its first step"
    for state, gap, v_f, v in seen:
        wish = LCA_LEFT | LCA_STRATEGIC | LCA_URGENT
        assert state & wish == wish
        assert state & LCA_BLOCKED_BY_LEFT_FOLLOWER
        assert gap < idm_secure_gap(v_f, v)
    assert change["reason"] == "strategic|urgent" and change["dir"] == "1"
    v_f, v = float(change["followerSpeed"]), float(change["speed"])
    assert v_f < V_MAX - 1  # the follower braked to let it in
    assert float(change["followerSecureGap"]) == pytest.approx(
        idm_secure_gap(v_f, v), abs=0.02
    )
    assert float(change["followerGap"]) - MIN_GAP >= float(change["followerSecureGap"])
