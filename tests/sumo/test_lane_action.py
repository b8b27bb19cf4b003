"""The AVs' lane action on the two-lane roundabout, in SUMO and in JAX.

A scripted lane rule (``gap:5``, `jaxround.envs.scripted_lanes`) drives half
the vehicles in both simulators on the same schedule. SUMO's controller
reads every vehicle onto its lane path (`jaxround.lanes.tracking`) and
computes the ``"lanes"`` observation with the JAX environment's own
observer; its lane-index column must be SUMO's own lane index for every
vehicle at every step, and while both simulators hold the same traffic
(every vehicle on the same lane path, at the same position and speed: the
first steps, before one decision differs) the rows must agree.
Measured (2026-11-27): 120 steps, every lane index right; 88 rows over
the first 31 steps within 2.6e-6; 1,027 requests sent (holds included),
66 lane changes in SUMO, 0 collisions. Neither simulator sends a request
from a junction or from where the step's move could reach one
(`jaxround.envs.lane_view`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common.evaluation import with_observer
from jaxround.apps.drivers import jax_driver, parse_driver
from jaxround.envs.lane_view import LANE_INDEX
from jaxround.envs.roundabout import make
from jaxround.lanes.ring_changer import locate
from jaxround.scenario.schedule import make_schedule
from sumo_export.runner import run_schedule
from sumo_export.scenario import vehicle_id
from sumo_export.scripted import ScriptedControllerFactory
from sumo_export.traffic import COLUMNS
from tests.conftest import small_config

pytestmark = pytest.mark.sumo

SPEC = "gap:5"
N_STEPS = 120
#: State agreement under which two observation rows must agree.
POS_TOL, SPEED_TOL = 1e-4, 1e-5
OBS_TOL = 1e-4


@pytest.fixture(scope="module")
def runs() -> dict[str, Any]:
    cfg = small_config("two_lane", n_vehicles=60, duration_s=140.0)
    cfg = with_observer(cfg, "lanes")
    schedule = make_schedule(cfg, seed=0, penetration=0.5)

    # SUMO: the scripted controller, its rows and SUMO's own lane indices
    ctrl = ScriptedControllerFactory(SPEC)(cfg, schedule)
    ctrl.record_observations = True
    sumo_rows: list[dict[str, Any]] = []
    wrong_lanes: list[str] = []
    sent: list[tuple[str, float, float, float]] = []

    patched: dict[str, Any] = {}

    def record(libsumo: Any, t: float) -> None:
        if not patched:  # every request as SUMO gets it: lane, position, speed
            change_lane = libsumo.vehicle.changeLane
            patched.update(module=libsumo.vehicle, change_lane=change_lane)

            def recorded(vid: str, index: int, duration: float) -> None:
                lane = libsumo.vehicle.getLaneID(vid)
                sent.append((lane, libsumo.vehicle.getLanePosition(vid),
                             libsumo.vehicle.getSpeed(vid),
                             libsumo.lane.getLength(lane)))  # fmt: skip
                change_lane(vid, index, duration)

            libsumo.vehicle.changeLane = recorded
        ctrl(libsumo, t)
        if len(sumo_rows) >= N_STEPS:
            return
        traffic, obs = ctrl.last_traffic, ctrl.last_obs
        state = traffic.packed[:, [COLUMNS.index(c) for c in ("route", "pos", "speed")]]
        for k, vid in enumerate(traffic.ids):
            if obs[k, LANE_INDEX] != libsumo.vehicle.getLaneIndex(vid):
                wrong_lanes.append(f"{t}: {vid}")
        sumo_rows.append({vid: (state[k], obs[k]) for k, vid in enumerate(traffic.ids)})

    try:
        run = run_schedule(cfg, schedule, controller=record)
    finally:  # libsumo's module outlives the run: its own changeLane back
        if patched:
            patched["module"].changeLane = patched["change_lane"]

    # JAX: the same rule on the environment's own state
    env, params = make(cfg, max_vehicles=32)
    policy = jax_driver(env, params, parse_driver(SPEC))

    @jax.jit
    def step(state, obs):
        action = policy(obs, state, None)
        return env.step_env(jax.random.PRNGKey(0), state, action, params)

    @jax.jit
    def requests(state, obs):
        """The step's requests and, for each AV that asks, whether it is on
        a junction or could reach one in the step's move."""
        action = policy(obs, state, None)
        agent = state.active & state.is_av
        car = params.for_vehicles(state.is_av)
        asked = env.lane_changer.request(state, action[:, 1], agent, car)
        arrays = env.lane_changer.arrays
        _, lane, on_lane = locate(arrays, state.route, state.pos)
        reach = (state.speed + car.accel * env.dt) * env.dt
        near = arrays.lane_internal[lane] | (
            on_lane + reach >= arrays.lane_length[lane]
        )
        return asked, agent & ~jnp.isnan(action[:, 1]) & near

    obs, state = env.reset_to_schedule(env.schedule_from_numpy(schedule), params)
    jax_rows = []
    sent_near = withheld = 0
    for _ in range(N_STEPS):
        asked, near = jax.device_get(requests(state, obs))
        sent_near += int(np.sum((asked >= 0) & near))
        withheld += int(np.sum(near))
        s, o = jax.device_get((state, obs))
        jax_rows.append({
            vehicle_id(int(s.vid[m])):
                (np.array([s.route[m], s.pos[m], s.speed[m]]), o[m])
            for m in np.nonzero(s.active)[0]
        })  # fmt: skip
        obs, state, _, _, info = step(state, obs)
        assert int(info["overflow"]) == 0
    return {
        "run": run, "report": ctrl.report(), "wrong_lanes": wrong_lanes,
        "sumo_rows": sumo_rows, "jax_rows": jax_rows,
        "jax_changes": int(np.sum(state.lanes.changes)),
        "sent": sent, "jax_sent_near": sent_near,
        "jax_withheld": withheld, "av_accel": cfg.drivers.av.accel,
        "dt": cfg.simulation.dt_s,
    }  # fmt: skip


def test_the_sumo_observer_follows_every_vehicle_onto_its_lane(runs) -> None:
    assert len(runs["sumo_rows"]) == N_STEPS
    assert runs["wrong_lanes"] == []
    assert runs["report"]["off_path_vehicle_steps"] == 0
    assert runs["report"]["overflow_vehicle_steps"] == 0


def test_the_rule_asks_and_both_simulators_change_lanes_safely(runs) -> None:
    print(
        f"requests {runs['report']['lane_requests']}, changes SUMO "
        f"{runs['run'].lane_changes} JAX {runs['jax_changes']}"
    )
    assert runs["report"]["lane_requests"] > 20
    assert runs["run"].lane_changes > 0 and runs["jax_changes"] > 0
    assert runs["run"].collisions == 0 and runs["run"].teleports == 0


def test_no_request_is_sent_on_or_just_before_a_junction(runs) -> None:
    """SUMO changes lanes on the ring's through internal edges, where its
    checks miss the vehicle on the exit's internal lane beside; neither
    simulator sends a request from there, nor from where the step's move
    could reach there (at most the AV's accel more speed)."""
    accel, dt = runs["av_accel"], runs["dt"]
    report = runs["report"]
    print(
        f"SUMO sent {report['lane_requests']}, withheld "
        f"{report['lane_requests_withheld']}; JAX withheld {runs['jax_withheld']}"
    )
    assert len(runs["sent"]) == report["lane_requests"] > 20
    for lane, pos, speed, length in runs["sent"]:
        assert not lane.startswith(":"), lane
        assert pos + (speed + accel * dt) * dt < length, (lane, pos, speed)
    assert report["lane_requests_withheld"] > 10
    assert runs["jax_withheld"] > 10 and runs["jax_sent_near"] == 0


def test_rows_agree_while_the_traffic_does(runs) -> None:
    errors, steps = [], 0
    tol = np.array([0.0, POS_TOL, SPEED_TOL])  # the same lane path
    for j, s in zip(runs["jax_rows"], runs["sumo_rows"], strict=True):
        same = set(j) == set(s) and all(
            np.all(np.abs(j[v][0] - s[v][0]) <= tol) for v in j
        )
        if not same:
            break
        steps += 1
        errors += [float(np.abs(j[v][1] - s[v][1]).max()) for v in j]
        for v in j:
            d = np.abs(j[v][1] - s[v][1])
            if d.max() > OBS_TOL:
                print(
                    "DBG step",
                    steps,
                    v,
                    np.nonzero(d > OBS_TOL)[0],
                    j[v][1][d > OBS_TOL],
                    s[v][1][d > OBS_TOL],
                    j[v][0],
                )
    print(f"{len(errors)} rows over {steps} steps, max |error| {max(errors):.1e}")
    assert steps >= 20 and len(errors) >= 60
    assert max(errors) < OBS_TOL
