"""What the road holds (`jaxround.core.capacity`), the default vehicle slots
sized by the traffic, and runs redone when their slots overflow
(`jaxround.envs.slots`)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.apps.cli.arguments import warn_slot_overflow
from jaxround.core.capacity import (
    lane_capacities,
    length_with_gap,
    overflow_warning,
    road_capacity,
)
from jaxround.envs import slots as slot_sizing
from jaxround.envs.rollout import uncontrolled_policy
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ConfigError, config_from_dict, load_config
from jaxround.scenario.schedule import make_schedule
from jaxround.sumo_files.compile import compile_network
from jaxround.sumo_files.netconvert import network_file
from tests.conftest import builtin_dict

#: Milan's road, by hand (vehicles 5 m long with a 2.5 m minGap: 7.5 m apart):
#: 8 approach and exit lanes of 43.34 m hold ceil(43.34 / 7.5) = 6 fronts each,
#: 8 entry and exit junction lanes of 8.92 m hold 2, the 4 ring through
#: lanes of 13.86 m hold 2 and the 4 ring edges of 7.45 m hold 1.
MILAN_BY_HAND = 8 * 6 + 8 * 2 + 4 * 2 + 4 * 1


@pytest.fixture(scope="module")
def milan_net() -> Any:
    cfg = load_config("milan")
    return cfg, compile_network(network_file(cfg), cfg.n_legs)


def test_milan_capacity_by_hand(milan_net: Any) -> None:
    cfg, net = milan_net
    lengths = sorted(np.round(net.lane_length, 2))
    assert lengths == sorted([43.34] * 8 + [8.92] * 8 + [13.86] * 4 + [7.45] * 4)
    assert length_with_gap(cfg) == 7.5
    assert road_capacity(net, cfg) == MILAN_BY_HAND == 76


def test_lane_capacity_counts_fronts() -> None:
    # a lane shorter than the spacing still holds one front; an exact
    # multiple k * spacing holds k (fronts at 0, s, ..., (k - 1) s)
    got = lane_capacities(np.array([7.45, 7.5, 15.0, 15.01, 0.3]), 7.5)
    assert got.tolist() == [1, 1, 2, 3, 1]
    with pytest.raises(ValueError, match="spacing"):
        lane_capacities(np.array([1.0]), 0.0)


def test_smallest_vtype_spacing(milan_net: Any) -> None:
    cfg, net = milan_net
    d = builtin_dict()
    d["drivers"]["av"]["min_gap"] = 1.0  # AVs closer: 6 m apart
    short = config_from_dict(d)
    assert length_with_gap(short) == 6.0
    assert road_capacity(net, short) == int(np.ceil(net.lane_length / 6.0).sum())


def builder(cfg: Any, net: Any) -> slot_sizing.EnvFactory:
    """What `RoundaboutEnv` gives `resolve_slots`: its own kind, built."""
    from jaxround.envs.roundabout import RoundaboutEnv

    return lambda m, seconds: RoundaboutEnv(cfg, net, m, episode_s=seconds)


def test_slots_given_then_config_then_traffic(milan_net: Any) -> None:
    cfg, net = milan_net
    sizing = slot_sizing.traffic_slots(cfg, net, builder(cfg, net))
    assert (
        slot_sizing.resolve_slots(None, cfg, net, builder(cfg, net))
        == sizing.max_vehicles
    )
    # Milan at its demand: far fewer vehicles than the road holds, a margin
    # above the most any measured step held
    assert sizing.road == 76 and 8 <= sizing.peak < sizing.max_vehicles <= 40
    assert sizing.max_vehicles == slot_sizing.slots_for_peak(sizing.peak, 76)
    assert slot_sizing.resolve_slots("road", cfg, net, builder(cfg, net)) == 76
    capped = cfg.with_overrides(max_vehicles=40)
    assert slot_sizing.resolve_slots(None, capped, net, builder(capped, net)) == 40
    assert slot_sizing.resolve_slots(12, capped, net, builder(capped, net)) == 12
    for bad in (0, -3, 2.5, True, "many"):
        with pytest.raises(ValueError, match="max_vehicles"):
            slot_sizing.resolve_slots(bad, cfg, net, builder(cfg, net))


def test_slots_for_peak() -> None:
    assert slot_sizing.slots_for_peak(20, 76) == 32  # 25 rounded up to 8s
    assert slot_sizing.slots_for_peak(24, 76) == 32
    assert slot_sizing.slots_for_peak(26, 76) == 40
    assert slot_sizing.slots_for_peak(1, 76) == 8  # at least 8
    assert slot_sizing.slots_for_peak(70, 76) == 76  # at most the road's


def test_sizing_cached_per_scenario(
    milan_net: Any, tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, net = milan_net
    d = builtin_dict()  # Milan's roads, a short demand: quick to measure
    d["demand"]["n_vehicles"], d["demand"]["duration_s"] = 30, 60.0
    cfg = config_from_dict(d)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    path = slot_sizing._cache_file(cfg)
    assert not path.exists()
    path.parent.mkdir(parents=True)
    path.write_text("{not json")  # a damaged cache is measured again
    calls = []
    real = slot_sizing.peak_occupancy

    def counted(*args: Any) -> tuple[int, int]:
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(slot_sizing, "peak_occupancy", counted)
    first = slot_sizing.traffic_slots(cfg, net, builder(cfg, net))
    second = slot_sizing.traffic_slots(cfg, net, builder(cfg, net))
    assert first == second and len(calls) == 1 and path.exists()


def test_redo_on_overflow_until_none() -> None:
    notes: list[str] = []
    seen: list[int] = []

    def run(m: int) -> int:  # "overflow" while fewer than 30 slots
        seen.append(m)
        return max(0, 30 - m)

    result, tried = slot_sizing.redo_on_overflow(
        run, lambda o: o, max_vehicles=8, road=76, what="test", note=notes.append
    )
    assert result == 0 and tried == seen == [8, 16, 32]
    assert len(notes) == 2 and "max_vehicles = 16" in notes[1]
    assert "redone with 32 slots" in notes[1]
    # the road's capacity is the last resort
    _, tried = slot_sizing.redo_on_overflow(
        run, lambda o: o, max_vehicles=20, road=24, what="test", note=notes.append
    )
    assert tried == [20, 24]


@pytest.mark.parametrize("value", [0, -1, 2.5, "many", True])
def test_config_field_checked(value: Any) -> None:
    d = builtin_dict()
    d["simulation"]["max_vehicles"] = value
    with pytest.raises(ConfigError, match=r"simulation\.max_vehicles"):
        config_from_dict(d)


def test_config_field_null_and_set() -> None:
    d = builtin_dict()
    d["simulation"]["max_vehicles"] = None
    assert config_from_dict(d).simulation.max_vehicles is None
    d["simulation"]["max_vehicles"] = 24
    assert config_from_dict(d).simulation.max_vehicles == 24


def test_overflow_warning(capsys: pytest.CaptureFixture[str]) -> None:
    assert overflow_warning(0, 32) is None
    text = overflow_warning(120, 32, "parity")
    assert "120 vehicle-steps" in text and "max_vehicles = 32" in text
    assert "--max-vehicles" in text
    warn_slot_overflow({"max_vehicles": 32, "jax_slot_overflow": 0}, "parity")
    assert capsys.readouterr().err == ""
    warn_slot_overflow({"max_vehicles": 32, "jax_slot_overflow": 7}, "bench")
    err = capsys.readouterr().err
    assert err.startswith("warning: bench: 7 vehicle-steps") and "32" in err


def past_capacity() -> Any:
    """Milan with 150 m legs and about 6000 vehicles an hour: queues on every
    approach, more vehicles on the road than 32 slots hold."""
    d = builtin_dict()
    d["name"] = "milan_past_capacity"
    for leg in d["network"]["legs"]:
        leg["length_m"] = 150.0
    d["demand"]["n_vehicles"] = 250
    d["demand"]["duration_s"] = 150.0
    return config_from_dict(d)


def peak_and_overflow(cfg: Any, max_vehicles: int | None, steps: int) -> tuple:
    env, params = make(cfg, max_vehicles=max_vehicles)
    policy = uncontrolled_policy(env)
    schedule = env.schedule_from_numpy(make_schedule(cfg, seed=0))

    @jax.jit
    def run(schedule: Any) -> tuple[jax.Array, jax.Array]:
        obs, state = env.reset_to_schedule(schedule, params)

        def body(carry: Any, _: None) -> tuple[Any, jax.Array]:
            obs, state = carry
            action = policy(obs, state, None)
            obs, state, *_ = env.step_env(jax.random.PRNGKey(0), state, action, params)
            return (obs, state), jnp.sum(state.active)

        (_, state), n_active = jax.lax.scan(body, (obs, state), None, length=steps)
        return jnp.max(n_active), state.stats.overflow

    peak, overflow = run(schedule)
    return env.max_vehicles, int(peak), int(overflow)


def test_past_capacity_no_overflow_at_the_roads_slots() -> None:
    cfg = past_capacity()
    steps = 360  # 180 s: the approaches fill
    m, peak, overflow = peak_and_overflow(cfg, "road", steps)
    assert overflow == 0 and peak <= m
    assert peak > 32  # more than 32 slots would hold ...
    m32, peak32, overflow32 = peak_and_overflow(cfg, 32, steps)
    assert m32 == 32 and peak32 == 32 and overflow32 > 0  # ... which overflow


def test_parity_runs_redone_with_more_slots(capsys: pytest.CaptureFixture) -> None:
    """A run that needs more slots than it was given gets them by itself:
    the overflowing run is redone, said on stderr, and never reported."""
    from jaxround.apps.parity import run_jax

    d = builtin_dict()  # Milan at twice its demand, for two minutes
    d["demand"]["n_vehicles"], d["demand"]["duration_s"] = 100, 120.0
    runs = run_jax(config_from_dict(d), [0], max_vehicles=12, cap_s=120.0)
    tried = runs[0]["max_vehicles_tried"]
    assert tried[:2] == [12, 24] and runs[0]["max_vehicles"] == tried[-1]
    assert runs[0]["overflow"] == 0 and runs[0]["records"].arrived.sum() > 50
    assert "max_vehicles = 12; redone with 24 slots" in capsys.readouterr().err
