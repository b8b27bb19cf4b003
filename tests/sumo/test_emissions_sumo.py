"""HBEFA4/PC_petrol_Euro-4 emissions: hand-computed rates and parity with SUMO 1.28.

The SUMO tests drive a few vehicles along a straight two-edge road in libsumo
(one of them scripted with ``setSpeed`` through hard acceleration, coasting,
hard braking and a standstill), record every speed, and recompute SUMO's
``--emission-output`` step by step and tripinfo's ``CO2_abs`` / ``fuel_abs``
trip by trip from those speeds alone.
"""

from __future__ import annotations

import math
import os
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core import emissions

DT = 0.5
G_SIN = 9.80665 * math.sin(math.radians(2.0))  # a' - a on a 2 deg uphill
G_SIN_DOWN = 9.80665 * math.sin(math.radians(-3.0))

# (v, a, slope, CO2, fuel) by hand from f = CO2_COEFFS / FUEL_COEFFS:
# CO2 = 1521 + 15.59 v + 695.1 a + 0.1199 v^3 + 132.5 a v + 3.434 a v^2.
HAND_VALUES = [
    pytest.param(0.0, 0.0, 0.0, 1521.0, 493.1, id="idling"),
    pytest.param(0.0, 1.0, 0.0, 2216.1, 718.4, id="pulling-away"),
    pytest.param(0.0, -3.0, 0.0, 0.0, 0.0, id="standstill-floored-at-0"),
    pytest.param(10.0, 0.0, 0.0, 1796.8, 582.51, id="cruising"),
    pytest.param(10.0, 2.0, 0.0, 6523.8, 2114.91, id="hard-acceleration"),
    pytest.param(10.0, -0.2, 0.0, 1324.1, 429.27, id="gentle-coast-above-cut"),
    pytest.param(10.0, -0.3, 0.0, 0.0, 0.0, id="coasting-cut"),
    pytest.param(0.5, -1.0, 0.0, 766.6013875, 248.57360875, id="no-cut-at-0.5"),
    pytest.param(0.51, -1.0, 0.0, 0.0, 0.0, id="cut-above-0.5"),
    pytest.param(1.0, -0.04, 0.0, 1503.46854, 487.41795, id="low-speed-no-cut"),
    pytest.param(1.0, -0.06, 0.0, 0.0, 0.0, id="low-speed-cut"),
    pytest.param(
        10.0, 0.0, 2.0, 1796.8 + 2363.5 * G_SIN, 582.51 + 766.2 * G_SIN, id="uphill"
    ),
    pytest.param(
        10.0,
        0.0,
        -3.0,
        1796.8 + 2363.5 * G_SIN_DOWN,
        582.51 + 766.2 * G_SIN_DOWN,
        id="downhill-a=0-not-cut",
    ),
    pytest.param(10.0, -0.01, -3.0, 0.0, 0.0, id="downhill-braking-cut"),
]


@pytest.mark.parametrize(("v", "a", "slope", "co2", "fuel"), HAND_VALUES)
def test_rates_hand_computed(v, a, slope, co2, fuel):
    got_co2, got_fuel = emissions.hbefa4_rates(v, a, slope)
    np.testing.assert_allclose(float(got_co2), co2, rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(float(got_fuel), fuel, rtol=1e-6, atol=1e-3)


def test_coasting_threshold():
    d = emissions.coasting_decel([0.0, 1.0, 10.0, 10.0], [0.0, 0.0, 0.0, -3.0])
    np.testing.assert_allclose(d, [0.0, -0.051838, -0.2377148, 0.0], atol=2e-6)


def test_step_and_trip_are_jittable_and_vmappable():
    v_old = jnp.array([0.0, 5.0, 12.0])
    v_new = jnp.array([1.5, 5.0, 11.0])
    step = jax.jit(jax.vmap(emissions.step_emissions_mg, in_axes=(0, 0, None, 0)))
    co2, fuel = step(v_old, v_new, DT, jnp.array([1.0, 1.0, 0.5]))
    assert co2.shape == fuel.shape == (3,)
    rate_co2, _ = emissions.hbefa4_rates(v_new, (v_new - v_old) / DT)
    np.testing.assert_allclose(
        co2, rate_co2 * DT * jnp.array([1.0, 1.0, 0.5]), rtol=1e-6
    )

    v_steps = jnp.array([[1.0, 2.0, 3.0], [0.5, 0.0, 9.0]])  # (2, T=3)
    valid = jnp.array([[True, True, True], [True, True, False]])
    co2, fuel = jax.jit(emissions.trip_emissions_mg)(
        jnp.array([0.0, 1.0]), v_steps, DT, valid
    )
    assert co2.shape == fuel.shape == (2,)
    first, _ = emissions.step_emissions_mg(1.0, 0.5, DT)
    second, _ = emissions.step_emissions_mg(0.5, 0.0, DT)
    np.testing.assert_allclose(co2[1], first + second, rtol=1e-6)


# --------------------------------------------------------------------------
# Parity with SUMO


def _sumo_bin(name: str) -> str:
    import sumo

    return os.path.join(sumo.SUMO_HOME, "bin", name)


NODES = """<nodes>
    <node id="A" x="0" y="0"/><node id="B" x="300" y="0"/><node id="C" x="600" y="0"/>
</nodes>"""
EDGES = """<edges>
    <edge id="AB" from="A" to="B" numLanes="1" speed="13.89"/>
    <edge id="BC" from="B" to="C" numLanes="1" speed="13.89"/>
</edges>"""
VTYPE = (
    'carFollowModel="IDM" accel="1.7634" decel="4.2939" tau="1.3472" '
    'speedDev="0" emissionClass="HBEFA4/PC_petrol_Euro-4"'
)
ROUTES = f"""<routes>
    <vType id="idm" {VTYPE}/>
    <vType id="scripted" {VTYPE}/>
    <route id="r" edges="AB BC"/>
    <vehicle id="ctl" type="scripted" route="r" depart="0" departSpeed="0"
             arrivalPos="150"/>
    <vehicle id="idm0" type="idm" route="r" depart="2" departSpeed="0"/>
    <vehicle id="idm1" type="idm" route="r" depart="6" departSpeed="max"
             arrivalPos="255.5"/>
    <vehicle id="idm2" type="idm" route="r" depart="10" departSpeed="5"
             arrivalPos="123.45"/>
    <vehicle id="idm3" type="idm" route="r" depart="25" departPos="100"
             departSpeed="0" arrivalPos="33.3"/>
</routes>"""


def _scripted_speed(t: float, v: float) -> float:
    """Target speed of the scripted vehicle for the step starting at time t."""
    if t < 5.0:  # hard acceleration, 3 m/s^2 (above its vType accel)
        return min(12.0, v + 3.0 * DT)
    if t < 9.0:  # cruise
        return 12.0
    if t < 13.0:  # gentle coast, -0.15 m/s^2: the engine keeps running
        return v - 0.15 * DT
    if t < 16.0:  # coast at -0.5 m/s^2: fuel cut
        return v - 0.5 * DT
    if t < 19.5:  # hard braking to a standstill
        return max(0.0, v - 4.0 * DT)
    if t < 26.0:  # standstill
        return 0.0
    return min(10.0, v + 1.5 * DT)  # pull away and cruise to the arrival


@pytest.fixture(scope="module")
def sumo_run(tmp_path_factory) -> dict[str, Any]:
    """Run the scenario once; return speeds, emission-output and tripinfo."""
    import libsumo

    d: Path = tmp_path_factory.mktemp("emissions")
    (d / "n.nod.xml").write_text(NODES)
    (d / "e.edg.xml").write_text(EDGES)
    (d / "r.rou.xml").write_text(ROUTES)
    subprocess.run(
        [_sumo_bin("netconvert"), "-n", str(d / "n.nod.xml"), "-e",
         str(d / "e.edg.xml"), "-o", str(d / "net.xml"), "--no-turnarounds", "true"],
        check=True, capture_output=True,
    )  # fmt: skip
    libsumo.start(
        ["sumo", "-n", str(d / "net.xml"), "-r", str(d / "r.rou.xml"),
         "--step-length", str(DT), "--no-step-log", "true", "--no-warnings", "true",
         "--device.emissions.probability", "1", "--precision", "8",
         "--emission-output", str(d / "em.xml"),
         "--tripinfo-output", str(d / "ti.xml")]
    )  # fmt: skip
    speeds: dict[str, dict[int, float]] = {}  # vid -> {step: speed after it}
    try:
        while libsumo.simulation.getMinExpectedNumber() > 0:
            t = libsumo.simulation.getTime()  # start of the step about to run
            if "ctl" in libsumo.vehicle.getIDList():
                libsumo.vehicle.setSpeedMode("ctl", 0)
                v = libsumo.vehicle.getSpeed("ctl")
                libsumo.vehicle.setSpeed("ctl", _scripted_speed(t, v))
            libsumo.simulationStep()
            # outputs of this step are stamped with its start time t
            k = round(t / DT)
            for vid in libsumo.vehicle.getIDList():
                speeds.setdefault(vid, {})[k] = libsumo.vehicle.getSpeed(vid)
    finally:
        libsumo.close()

    em: dict[str, dict[int, tuple[float, float, float]]] = {}
    for step in ET.parse(d / "em.xml").getroot().iter("timestep"):
        k = round(float(step.get("time")) / DT)
        for veh in step.iter("vehicle"):
            em.setdefault(veh.get("id"), {})[k] = (
                float(veh.get("CO2")), float(veh.get("fuel")), float(veh.get("speed"))
            )  # fmt: skip
    trips = {}
    for trip in ET.parse(d / "ti.xml").getroot().iter("tripinfo"):
        e = trip.find("emissions")
        trips[trip.get("id")] = {
            key: float(trip.get(key))
            for key in ("depart", "arrival", "departSpeed", "arrivalSpeed")
        } | {"CO2_abs": float(e.get("CO2_abs")), "fuel_abs": float(e.get("fuel_abs"))}
    return {"speeds": speeds, "em": em, "trips": trips}


@pytest.mark.sumo
def test_scenario_covers_every_regime(sumo_run):
    assert set(sumo_run["trips"]) == {"ctl", "idm0", "idm1", "idm2", "idm3"}
    rows = sumo_run["em"]["ctl"]
    v = np.array([rows[k][2] for k in sorted(rows)])
    co2 = np.array([rows[k][0] for k in sorted(rows)])[1:]
    a = np.diff(v) / DT
    assert (v == 0.0).sum() >= 10  # standstill
    assert a.max() >= 2.9 and a.min() <= -3.9  # hard acceleration and braking
    assert np.all(co2[np.isclose(a, -0.15)] > 0.0)  # gentle coast: engine on
    assert np.all(co2[np.isclose(a, -0.5)] == 0.0)  # coasting: fuel cut
    assert np.isclose(a, -0.5).sum() >= 5


@pytest.mark.sumo
def test_per_step_rates_match_emission_output(sumo_run):
    """Every emission-output row, recomputed from the libsumo speeds."""
    v_new, v_old, sumo_co2, sumo_fuel = [], [], [], []
    for vid, rows in sumo_run["em"].items():
        steps = sorted(rows)
        assert steps == sorted(sumo_run["speeds"][vid])
        v = np.array([sumo_run["speeds"][vid][k] for k in steps])
        np.testing.assert_allclose(v, [rows[k][2] for k in steps], atol=1e-7)
        v_new.append(v)
        v_old.append(np.concatenate([v[:1], v[:-1]]))  # insertion step: a = 0
        sumo_co2.append([rows[k][0] for k in steps])
        sumo_fuel.append([rows[k][1] for k in steps])
    v_new, v_old = np.concatenate(v_new), np.concatenate(v_old)
    co2, fuel = emissions.hbefa4_rates(v_new, (v_new - v_old) / DT)
    for got, want in ((co2, sumo_co2), (fuel, sumo_fuel)):
        want = np.concatenate(want)
        err = np.abs(np.asarray(got, np.float64) - want)
        assert np.all(err <= np.maximum(1e-3, 1e-4 * np.abs(want))), err.max()
    assert len(v_new) > 500


def _trips(run: dict[str, Any]) -> dict[str, np.ndarray]:
    """All trips, padded to one length T.

    Per trip: the depart speed and the speed after every step from the one
    after insertion to the arrival step, whose speed only tripinfo knows.
    """
    depart, steps = [], []
    for vid, trip in run["trips"].items():
        k_depart, k_arrival = round(trip["depart"] / DT), round(trip["arrival"] / DT)
        speeds = run["speeds"][vid]
        assert min(speeds) == k_depart and max(speeds) == k_arrival - 1
        assert speeds[k_depart] == pytest.approx(trip["departSpeed"], abs=1e-7)
        depart.append(trip["departSpeed"])
        moved = [speeds[k] for k in range(k_depart + 1, k_arrival)]
        steps.append([*moved, trip["arrivalSpeed"]])
    n_steps = np.array([len(x) for x in steps])
    valid = np.arange(n_steps.max()) < n_steps[:, None]  # (n, T)
    v_steps = np.zeros(valid.shape)
    v_steps[valid] = np.concatenate(steps)
    trips = run["trips"].values()
    return {
        "v_depart": np.array(depart),  # (n,)
        "v_steps": v_steps,  # (n, T)
        "valid": valid,  # (n, T)
        "n_steps": n_steps,  # (n,)
        "co2": np.array([t["CO2_abs"] for t in trips]),  # (n,)
        "fuel": np.array([t["fuel_abs"] for t in trips]),  # (n,)
    }


@pytest.mark.sumo
@pytest.mark.parametrize("x64", [True, False], ids=["float64", "float32"])
def test_trip_totals_match_tripinfo(sumo_run, x64):
    """tripinfo counts every step after insertion, the arrival step fully."""
    trips = _trips(sumo_run)
    with jax.enable_x64(x64):
        co2, fuel = jax.jit(emissions.trip_emissions_mg)(
            trips["v_depart"], trips["v_steps"], DT, trips["valid"]
        )
        co2, fuel = np.asarray(co2, np.float64), np.asarray(fuel, np.float64)
    rtol = 1e-9 if x64 else 1e-6
    np.testing.assert_allclose(co2, trips["co2"], rtol=rtol)
    np.testing.assert_allclose(fuel, trips["fuel"], rtol=rtol)


@pytest.mark.sumo
def test_insertion_step_not_counted_and_arrival_step_weighted_fully(sumo_run):
    """The alternatives one might expect miss tripinfo by far more than 1e-3."""
    trips = _trips(sumo_run)
    last_two = np.stack([trips["v_steps"][i, n - 2 : n] for i, n in enumerate(
        trips["n_steps"])])  # fmt: skip

    @jax.jit
    def alternatives(v_depart, v_steps, valid, last_two):
        co2, _ = emissions.trip_emissions_mg(v_depart, v_steps, DT, valid)
        insertion, _ = emissions.hbefa4_rates(v_depart, 0.0)
        last, _ = emissions.step_emissions_mg(last_two[:, 0], last_two[:, 1], DT)
        return co2 + insertion * DT, co2 - 0.5 * last

    with jax.enable_x64(True):
        wrong_totals = alternatives(
            trips["v_depart"], trips["v_steps"], trips["valid"], last_two
        )
        wrong_totals = [np.asarray(x, np.float64) for x in wrong_totals]
    for wrong in wrong_totals:  # insertion step added, arrival step halved
        assert np.all(np.abs(wrong / trips["co2"] - 1.0) > 1e-3)


@pytest.mark.sumo
def test_rates_match_emissions_map_with_slopes(tmp_path):
    """SUMO's emissionsMap over (v, a, slope), slopes included."""
    out = tmp_path / "map.csv"
    subprocess.run(
        [_sumo_bin("emissionsMap"), "-e", "HBEFA4/PC_petrol_Euro-4",
         "--v-min", "0", "--v-max", "40", "--v-step", "1",
         "--a-min", "-4", "--a-max", "3", "--a-step", "0.25",
         "--s-min", "-4", "--s-max", "4", "--s-step", "2", "-o", str(out)],
        check=True, capture_output=True,
    )  # fmt: skip
    rows = [line.split(";") for line in out.read_text().split()]
    table = {
        p: np.array([[float(x) for x in (r[0], r[1], r[2], r[4])] for r in rows
                     if r[3] == p])
        for p in ("CO2", "fuel")
    }  # fmt: skip
    v, a, s, _ = table["CO2"].T
    assert len(v) == 41 * 29 * 5
    co2, fuel = emissions.hbefa4_rates(v, a, s)
    near_cut = np.abs(a - np.asarray(emissions.coasting_decel(v, s))) < 1e-4
    for got, want in ((co2, table["CO2"][:, 3]), (fuel, table["fuel"][:, 3])):
        err = np.abs(np.asarray(got, np.float64) - want)[~near_cut]
        # emissionsMap prints 6 significant digits
        assert np.all(err <= np.maximum(1e-2, 2e-5 * np.abs(want[~near_cut])))
