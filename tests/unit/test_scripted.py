"""Scripted controllers: specs, commands on hand-made rows, and a SUMO run."""

from __future__ import annotations

import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.analysis.metrics import class_metrics
from jaxround.envs.observe import DISTANCE_SCALE, RING_HORIZON_S, SPEED_SCALE
from jaxround.envs.roundabout import make
from jaxround.envs.scripted import (
    LEADER_GAP,
    LEADER_REL_SPEED,
    NO_COMMAND,
    OWN_SPEED,
    RING_ARRIVAL,
    TO_YIELD_LINE,
    controller_from_spec,
    is_scripted_spec,
)
from jaxround.scenario.schedule import make_schedule
from sumo_export.controller import PolicyController
from sumo_export.runner import run_schedule
from sumo_export.scripted import ScriptedControllerFactory, scripted_policy
from tests.conftest import small_config


def row(
    speed: float,
    gap: float | None = None,
    leader_speed: float | None = None,
    to_line: float = 60.0,
    ring_s: float | None = None,
) -> np.ndarray:
    """A rich observation row, float (17,); None: no leader / no ring vehicle."""
    obs = np.zeros(17, np.float32)
    obs[OWN_SPEED] = speed / SPEED_SCALE
    obs[LEADER_GAP] = 1.0 if gap is None else gap / DISTANCE_SCALE
    if leader_speed is not None:
        obs[LEADER_REL_SPEED] = (leader_speed - speed) / SPEED_SCALE
    obs[TO_YIELD_LINE] = np.clip(to_line / DISTANCE_SCALE, -1.0, 1.0)
    obs[RING_ARRIVAL] = 1.0 if ring_s is None else ring_s / RING_HORIZON_S
    return obs


def commands(spec: str, *rows: np.ndarray) -> np.ndarray:
    act = jax.jit(controller_from_spec(spec).act)
    return np.asarray(act(jnp.asarray(np.stack(rows))))


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("brake:1", "unknown controller 'brake'"),
        ("accel", "accel needs a value"),
        ("cruise:fast", "'fast' is not a number"),
        ("cruise:-2", "cruise needs a value >= 0"),
        ("accel:nan", "'nan' is not finite"),
        ("timed:0", "timed needs a value >= 0.5"),
        ("policy.npz", "unknown controller 'policy.npz'"),
        # lane rules (`jaxround.envs.scripted_lanes`)
        ("left", "unknown controller 'left'"),
        ("gap", r"expected gap:X \(m\)"),
        ("inner:3", "expected inner, without a value"),
        ("gap:-1", "gap needs a value >= 0"),
        ("gap:wide", "'wide' is not a number"),
        ("eco+middle", "unknown lane rule 'middle'"),
        ("eco+", "unknown lane rule ''"),
        ("brake+inner", "unknown controller 'brake'"),
    ],
)
def test_bad_specs_name_the_problem(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        controller_from_spec(spec)
    with pytest.raises(ValueError, match=message):
        ScriptedControllerFactory(spec)


def test_specs_and_defaults() -> None:
    assert controller_from_spec("eco").spec == "eco"
    assert controller_from_spec("eco:0.5").observer == "rich"
    assert is_scripted_spec("timed:2") and not is_scripted_spec("runs/ppo/policy")
    factory = ScriptedControllerFactory("accel:-1")
    assert pickle.loads(pickle.dumps(factory)) == factory


def test_accel_and_cruise_commands() -> None:
    rows = (row(4.0), row(10.0, gap=20.0, leader_speed=0.0))
    np.testing.assert_allclose(commands("accel:-1", *rows), [-1.0, -1.0])
    # (V - v) / dt with dt 0.5
    np.testing.assert_allclose(commands("cruise:6", *rows), [4.0, -8.0], rtol=1e-5)


def test_eco_brakes_evenly_only_to_a_certain_stop() -> None:
    got = commands(
        "eco:0.3",
        row(10.0, gap=20.0, leader_speed=0.0),  # standing queue 17.5 m ahead
        row(10.0, to_line=40.0),  # free entry
        row(10.0, to_line=40.0, ring_s=3.0),  # ring vehicle there when it arrives
        row(2.0, to_line=40.0, ring_s=3.0),  # gone long before it arrives
        row(3.0, gap=40.0, leader_speed=0.0),  # stop far: 0.12 m/s^2 < 0.3
        row(10.0, gap=20.0, leader_speed=5.0),  # the leader moves
        np.zeros(17, np.float32),  # an empty slot
    )
    expected = [
        -(10.0**2) / (2 * 17.5),
        NO_COMMAND,
        -(10.0**2) / (2 * 39.9),
        NO_COMMAND,
        NO_COMMAND,
        NO_COMMAND,
        NO_COMMAND,
    ]
    np.testing.assert_allclose(got, expected, rtol=1e-4)
    # a higher threshold waits for the stop at the line (1.25 m/s^2 needed)
    assert np.isnan(commands("eco:2", row(10.0, to_line=40.0, ring_s=3.0))[0])


def test_timed_reaches_the_line_after_the_ring_vehicle() -> None:
    got = commands(
        "timed:3",
        row(10.0, to_line=40.0, ring_s=3.0),  # arrive at 6 s at 80/6 - 10 m/s
        row(10.0, to_line=10.0, ring_s=5.0),  # enters first (1 s vs 5 s)
        row(10.0, to_line=10.0, ring_s=0.5),  # cannot arrive rolling: stop
        row(10.0, to_line=40.0),  # nothing on the ring
    )
    v_end = 80.0 / 6.0 - 10.0
    expected = [(v_end**2 - 100.0) / 80.0, NO_COMMAND, -100.0 / 20.0, NO_COMMAND]
    np.testing.assert_allclose(got, expected, rtol=1e-4)


def test_columns_read_what_the_environment_holds() -> None:
    """The column constants match `observe.rich_observation`: own speed,
    distance to the yield line and the leader's gap and speed of three
    vehicles placed by hand on one route."""
    cfg = small_config("milan", n_vehicles=40, duration_s=60.0)
    env, params = make(cfg, max_vehicles=8)
    sched = env.schedule_from_numpy(make_schedule(cfg, seed=1, penetration=1.0))
    _, state = jax.jit(env.reset_to_schedule)(sched, params)
    route = int(env.network.route_index[0, 2])
    line = float(env.network.yield_offset[route])
    pos = np.array([line - 30.0, line - 12.0, line - 3.0], np.float32)
    speed = np.array([9.0, 4.0, 0.0], np.float32)
    state = state.replace(
        active=state.active.at[:3].set(True),
        route=state.route.at[:3].set(route),
        pos=state.pos.at[:3].set(pos),
        speed=state.speed.at[:3].set(speed),
        is_av=state.is_av.at[:3].set(True),
    )
    obs = np.asarray(jax.jit(env.observation)(state, params))[:3]
    np.testing.assert_allclose(obs[:, OWN_SPEED] * SPEED_SCALE, speed, atol=1e-5)
    np.testing.assert_allclose(
        obs[:, TO_YIELD_LINE] * DISTANCE_SCALE, line - pos, atol=1e-4
    )
    length = float(params.vehicle.length)
    np.testing.assert_allclose(
        obs[:2, LEADER_GAP] * DISTANCE_SCALE, np.diff(pos) - length, atol=1e-4
    )
    np.testing.assert_allclose(
        obs[:2, LEADER_REL_SPEED] * SPEED_SCALE, np.diff(speed), atol=1e-5
    )


def test_slow_cruise_slows_the_crossing_in_sumo() -> None:
    """cruise:6 on every AV in SUMO (150 vehicles, half AVs; the legs' limit
    is 13.89 m/s): the AVs cross slower than uncontrolled, safely. (A
    constant accel:-1 would bring them to a standstill on the ring.)"""
    cfg = small_config("milan")
    schedule = make_schedule(cfg, seed=100, penetration=0.5)
    free = run_schedule(cfg, schedule)
    braking = PolicyController(cfg, schedule, scripted_policy("cruise:6", 0.5), "rich")
    slow = run_schedule(cfg, schedule, controller=braking)
    free_av = class_metrics(free.records, cfg.demand.duration_s)["av"]
    slow_av = class_metrics(slow.records, cfg.demand.duration_s)["av"]
    assert slow_av["n_arrived"] == free_av["n_arrived"] == schedule.n_av
    assert slow_av["mean_crossing_time_s"] > free_av["mean_crossing_time_s"] + 1.0
    assert braking.commands > 0
    assert slow.collisions == 0 and slow.teleports == 0
