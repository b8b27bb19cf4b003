"""SUMO scenario files and runs, with the real SUMO from PyPI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sumolib

from jaxround.analysis.metrics import class_metrics
from jaxround.scenario.config import load_config
from jaxround.scenario.edges import route_edges
from jaxround.scenario.schedule import make_schedule
from sumo_export.evaluate import sumo_sweep
from sumo_export.runner import run_schedule
from sumo_export.scenario import vehicle_id, write_scenario
from tests.conftest import small_config

pytestmark = pytest.mark.sumo


@pytest.mark.parametrize("name", ["three_leg", "milan", "six_leg"])
def test_network_is_a_single_ring_roundabout(tmp_path: Path, name: str) -> None:
    cfg = load_config(name)
    files = write_scenario(cfg, make_schedule(cfg), tmp_path)
    for path in (files.net, files.routes, files.sumocfg):
        assert path.exists()
    net = sumolib.net.readNet(str(files.net), withInternal=True)
    n = cfg.n_legs
    rounds = net.getRoundabouts()
    assert len(rounds) == 1
    assert sorted(rounds[0].getEdges()) == sorted(f"ring_{i}" for i in range(n))
    for i, leg in enumerate(cfg.network.legs):
        lane = net.getEdge(f"in_{i}").getLane(0)
        assert lane.getSpeed() == pytest.approx(leg.speed_limit_mps, abs=0.01)
        # the junction geometry takes a few metres off each approach.
        assert 0.8 * leg.length_m < lane.getLength() <= leg.length_m
        # every OD route is connected in the compiled network
        for j in range(n):
            if j != i:
                edges = [net.getEdge(e) for e in route_edges(i, j, n)]
                for a, b in zip(edges, edges[1:], strict=False):
                    assert b in a.getOutgoing(), (a.getID(), b.getID())
    # entries yield (minor link), the ring has priority
    for i in range(n):
        conns = net.getEdge(f"in_{i}").getOutgoing()[net.getEdge(f"ring_{i}")]
        assert conns[0].getState() == "m"


def test_route_file_carries_the_schedule(tmp_path: Path) -> None:
    cfg = small_config(n_vehicles=40, duration_s=120.0)
    s = make_schedule(cfg, seed=4, penetration=0.25)
    files = write_scenario(cfg, s, tmp_path)
    vehicles = list(sumolib.xml.parse(str(files.routes), "vehicle"))
    assert len(vehicles) == 40
    factor = s.class_speed_factors(cfg.drivers.hv.speed_dev, cfg.drivers.av.speed_dev)
    assert np.all(factor[s.is_av] == 1.0)  # the AVs' speedDev is 0
    np.testing.assert_array_equal(factor[~s.is_av], s.speed_factor[~s.is_av])
    for i, v in enumerate(vehicles):
        assert v.id == vehicle_id(i)
        assert float(v.depart) == s.depart_s[i]
        assert float(v.speedFactor) == factor[i]
        assert v.type == ("av" if s.is_av[i] else "hv")
        assert v.route == f"r_{s.origin[i]}_{s.destination[i]}"
        assert v.departSpeed == "max"


def test_sumo_run_records_every_vehicle(tmp_path: Path) -> None:
    cfg = small_config(n_vehicles=150, duration_s=600.0)
    s = make_schedule(cfg, seed=0, penetration=0.2)
    seen: dict[str, float] = {}

    def record_speed_factors(traci, t: float) -> None:
        for vid in traci.simulation.getDepartedIDList():
            seen[vid] = traci.vehicle.getSpeedFactor(vid)

    run = run_schedule(cfg, s, workdir=tmp_path, controller=record_speed_factors)
    r = run.records
    assert run.collisions == 0 and run.teleports == 0
    assert r.departed.all() and r.arrived.all()
    np.testing.assert_array_equal(r.is_av, s.is_av)
    assert np.all(r.depart_s >= r.scheduled_depart_s)
    # no vehicle is faster than driving its route at the fastest limit
    net = sumolib.net.readNet(str(tmp_path / "milan.net.xml"))
    min_len = min(net.getEdge(f"in_{i}").getLength() for i in range(cfg.n_legs))
    assert np.all(r.crossing_time_s > 2 * min_len / 13.89 / 1.3)
    assert np.all(r.co2_g > 0) and np.all(r.fuel_g > 0)
    # fuel and CO2 follow the same emission model: their ratio is nearly fixed
    ratio = r.co2_g / r.fuel_g
    assert 3.0 < ratio.mean() < 3.3 and ratio.std() < 0.05
    # SUMO used the schedule's speed factor (1 for AVs), not its own draw
    assert len(seen) == 150
    factor = s.class_speed_factors(cfg.drivers.hv.speed_dev, cfg.drivers.av.speed_dev)
    for i in range(150):
        assert seen[vehicle_id(i)] == pytest.approx(factor[i], abs=1e-9)
    m = class_metrics(r, cfg.demand.duration_s)
    assert m["av"]["n_vehicles"] == 30 and m["hv"]["n_vehicles"] == 120
    assert r.queue_mean_veh.shape == r.queue_max_veh.shape == (cfg.n_legs,)
    assert np.all(r.queue_max_veh >= r.queue_mean_veh)


@pytest.mark.parametrize("name", ["three_leg", "six_leg"])
def test_other_roundabouts_run_in_parallel_processes(name: str) -> None:
    cfg = small_config(name, n_vehicles=120, duration_s=400.0)
    out = sumo_sweep(cfg, [0.0, 0.5], [0, 1], workers=2, show_progress=False)
    for p, summary in out.items():
        assert len(summary["per_seed"]) == 2
        mean = summary["mean"]
        assert mean["all"]["n_departed"] == 120
        assert mean["all"]["n_arrived"] == 120
        assert mean["collisions"] == 0 and mean["teleports"] == 0
        assert mean["all"]["mean_crossing_time_s"] > 0
        assert (mean["av"]["n_vehicles"] == 60) == (p == 0.5)


def test_scenario_folders_take_the_network_from_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """netconvert runs once per network: a second scenario folder of the same
    network (another demand) copies the cached .net.xml, which its .sumocfg
    names beside it."""
    import subprocess

    from jaxround.sumo_files import netconvert

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    calls = []
    real_run = subprocess.run

    def counting_run(cmd, *args, **kwargs):
        calls.append(cmd[0])
        return real_run(cmd, *args, **kwargs)

    monkeypatch.setattr(netconvert.subprocess, "run", counting_run)
    first = small_config("three_leg", n_vehicles=10, duration_s=30.0)
    second = small_config("three_leg", n_vehicles=20, duration_s=60.0)
    files = [
        write_scenario(cfg, make_schedule(cfg), tmp_path / name)
        for cfg, name in ((first, "a"), (second, "b"))
    ]
    assert len(calls) == 1 and "netconvert" in Path(calls[0]).name
    cached = netconvert.network_file(first)
    assert len(calls) == 1  # the JAX side's network is the same file
    for f in files:
        assert f.net.parent == f.sumocfg.parent
        assert f.net.read_bytes() == cached.read_bytes()
        assert f'<net-file value="{f.net.name}"/>' in f.sumocfg.read_text()
        assert (f.net.parent / "three_leg.nod.xml").is_file()
    run = run_schedule(first, make_schedule(first), workdir=tmp_path / "run")
    assert run.records.arrived.sum() > 0
