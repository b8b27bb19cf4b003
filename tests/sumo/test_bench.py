"""The benchmark on a small scenario: the shape of its result, not its timings."""

from __future__ import annotations

import json
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.common.config import load_ppo_config
from jaxround.apps import bare_ring
from jaxround.apps.bench import (
    batch_schedules,
    format_benchmark,
    run_benchmark,
    usable_cpus,
)
from jaxround.envs.roundabout import make
from jaxround.scenario.schedule import make_schedule
from tests.conftest import small_config

BATCHES = (4,)
SLOT_SIZES = (8, 16)
#: The timed training: milan's network, short episodes, 8 slots, 4 x 8
#: env-steps per update (the policy rollouts run the full milan demand).
TINY_PPO = dict(
    demand_window_s=20.0,
    episode_s=10.0,
    max_vehicles=8,
    n_envs=4,
    n_steps=8,
    total_env_steps=4 * 8 * 4,
    hidden=[16, 16],
    epochs=2,
    minibatches=2,
)
POLICY_BATCH = 2


@pytest.fixture(scope="module")
def result() -> dict[str, Any]:
    # M = 16 at batch 4 serves both the batch table and the slot table: two
    # compilations in all.
    return run_benchmark(
        small_config(n_vehicles=150, duration_s=600.0),
        batches=BATCHES,
        sim_seconds=5.0,
        max_vehicles=16,
        slot_sizes=SLOT_SIZES,
        progress=False,
        slot_batch=4,
        training=load_ppo_config("ppo_milan").replace(**TINY_PPO),
        policy_batch=POLICY_BATCH,
        policy_seconds=5.0,
    )


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


@pytest.mark.sumo
def test_result_has_the_documented_shape(result: dict[str, Any]) -> None:
    for key in (
        "sumo_vehicle_steps_per_s",
        "sumo_parallel",
        "jax",
        "best_ratio_vs_sumo",
        "best_ratio_vs_sumo_per_cpu_s",
        "best_ratio_vs_sumo_parallel",
        "slots",
        "machine",
        "sim_seconds",
    ):
        assert key in result
    assert result["sim_seconds"] == pytest.approx(5.0)
    assert [row["batch"] for row in result["jax"]] == list(BATCHES)
    for row in result["jax"]:
        for key in ("vehicle_steps_per_s", "steps_per_s", "compile_s"):
            assert _positive(row[key]), (key, row)
    assert [row["max_vehicles"] for row in result["slots"]] == list(SLOT_SIZES)
    for row in result["slots"]:
        assert _positive(row["us_per_step_per_roundabout"])
        assert _positive(row["us_per_vehicle_step"])
    machine = result["machine"]
    assert machine["jax_backend"] == "cpu"
    assert machine["jax_devices"]
    assert machine["sumo_version"].startswith("SUMO 1.28")
    assert machine["cpu_count"] >= 1
    json.dumps(result)  # plain data, as `jaxround bench --json` prints it


@pytest.mark.sumo
def test_each_sumo_process_is_timed_for_a_second(result: dict[str, Any]) -> None:
    """Repeats of the same simulated window until each process has timed at
    least `SUMO_MIN_TIMED_S` of wall time; the spread over them is kept."""
    from jaxround.apps.bench.sumo_timing import SUMO_MIN_TIMED_S

    assert SUMO_MIN_TIMED_S >= 1.0 and result["sumo_min_timed_s"] >= 1.0
    rows = [result["sumo"], *result["sumo_parallel"]["per_process"]]
    for row in rows:
        assert row["timed_wall_s"] >= SUMO_MIN_TIMED_S
        assert row["repeats"] > 1  # a 5 s window takes far less than a second
        spread = row["spread"]
        assert spread["p10"] <= spread["median"] <= spread["p90"]
        assert spread["relative"] >= 0
        assert row["jax"]["env"] == "cpu"
    assert result["sumo_parallel"]["min_timed_wall_s"] >= SUMO_MIN_TIMED_S
    device = result["device"]
    assert device["platform"] == "cpu" and device["kind"]
    assert device["batches"] == [1, 16, 256, 1024, 4096]
    assert device["training_n_envs"] == 64
    assert "repeats of the window" in format_benchmark(result)


@pytest.mark.sumo
def test_throughputs_are_consistent(result: dict[str, Any]) -> None:
    sumo = result["sumo_vehicle_steps_per_s"]
    assert _positive(sumo)
    # the network is not empty in the timed window, in either simulator
    assert result["sumo"]["vehicle_steps"] > 0
    best = max(row["vehicle_steps_per_s"] for row in result["jax"])
    assert result["best_ratio_vs_sumo"] == pytest.approx(best / sumo)
    steps = result["steps"]
    for row in result["jax"]:
        assert 0 < row["vehicle_steps"] <= row["batch"] * steps * 16
        # vehicle-steps and roundabout-steps are timed by the same runs
        ratio = row["vehicle_steps_per_s"] / row["steps_per_s"]
        assert ratio == pytest.approx(row["vehicle_steps"] / (row["batch"] * steps))
        assert row["overflow"] == 0
    # roundabout 0 runs SUMO's schedule: both see a populated network
    assert result["jax"][0]["mean_vehicles"] > 0


@pytest.mark.sumo
def test_ratios_per_cpu_second_and_against_sumo_on_every_core(
    result: dict[str, Any],
) -> None:
    sumo = result["sumo"]
    for row in result["jax"]:
        assert row["ratio_vs_sumo_per_cpu_s"] == pytest.approx(
            row["vehicle_steps_per_cpu_s"] / sumo["vehicle_steps_per_cpu_s"]
        )
    assert result["best_ratio_vs_sumo_per_cpu_s"] == pytest.approx(
        max(row["ratio_vs_sumo_per_cpu_s"] for row in result["jax"])
    )
    parallel = result["sumo_parallel"]
    assert parallel["processes"] == usable_cpus()
    assert len(parallel["per_process"]) == parallel["processes"]
    for row in parallel["per_process"]:
        assert _positive(row["vehicle_steps_per_s"])
        assert row["vehicle_steps"] > 0
    assert parallel["vehicle_steps_per_s"] == pytest.approx(
        sum(row["vehicle_steps_per_s"] for row in parallel["per_process"])
    )
    assert _positive(parallel["vehicle_steps_per_cpu_s"])
    best = max(row["vehicle_steps_per_s"] for row in result["jax"])
    assert result["best_ratio_vs_sumo_parallel"] == pytest.approx(
        best / parallel["vehicle_steps_per_s"]
    )


@pytest.mark.sumo
def test_flop_counts_and_the_bare_ring_yardstick(result: dict[str, Any]) -> None:
    for row in result["jax"]:
        assert _positive(row["flops_per_roundabout_step"])
        assert _positive(row["gflops_per_s"])
    bare = result["bare_ring"]
    assert bare["batch"] == result["best_batch"]
    assert bare["max_vehicles"] == result["max_vehicles"]
    assert _positive(bare["vehicle_steps_per_s"])
    assert bare["ratio_vs_sumo"] == pytest.approx(
        bare["vehicle_steps_per_s"] / result["sumo_vehicle_steps_per_s"]
    )
    # the yardstick is a small part of the environment's step
    env_flops = result["jax"][0]["flops_per_roundabout_step"]
    assert 0 < bare["flops_per_roundabout_step"] < env_flops / 5


@pytest.mark.sumo
def test_format_is_a_markdown_table(result: dict[str, Any]) -> None:
    text = format_benchmark(result)
    assert "| SUMO (libsumo) | 1 |" in text
    for b in BATCHES:
        assert f"| JAX | {b} |" in text
    for m in SLOT_SIZES:
        assert f"| {m} |" in text
    assert f"{result['best_ratio_vs_sumo']:.2f}x" in text
    assert f"per CPU-second {result['best_ratio_vs_sumo_per_cpu_s']:.2f}x" in text
    n = result["sumo_parallel"]["processes"]
    assert f"| SUMO (libsumo), {n} processes | {n} |" in text
    assert f"in {n} processes {result['best_ratio_vs_sumo_parallel']:.2f}x" in text
    assert "| bare IDM ring |" in text


@pytest.mark.sumo
def test_training_and_policy_rollouts_in_env_steps(result: dict[str, Any]) -> None:
    t = result["training"]
    ppo, jp, loop = t["ppo"], t["jax_policy"], t["sumo_in_the_loop"]
    for x in (t["ppo_env_steps_per_s"], t["jax_policy_env_steps_per_s"],
              t["sumo_in_the_loop_env_steps_per_s"], ppo["rollout_env_steps_per_s"],
              jp["vehicle_steps_per_s"], loop["vehicle_steps_per_s"]):  # fmt: skip
        assert _positive(x)
    assert t["ppo_vs_sumo_in_the_loop"] == pytest.approx(
        t["ppo_env_steps_per_s"] / t["sumo_in_the_loop_env_steps_per_s"]
    )
    assert t["jax_policy_vs_sumo_in_the_loop"] == pytest.approx(
        t["jax_policy_env_steps_per_s"] / t["sumo_in_the_loop_env_steps_per_s"]
    )
    assert t["ppo_vs_sumo_in_the_loop_per_cpu_s"] == pytest.approx(
        ppo["env_steps_per_cpu_s"] / loop["env_steps_per_cpu_s"]
    )
    cpu = sum(row["cpu_s"] for row in loop["per_process"])
    assert loop["env_steps_per_cpu_s"] == pytest.approx(loop["processes"] * 10 / cpu)
    # SUMO in the loop, too, repeats its window for at least a second
    assert loop["min_timed_wall_s"] >= 1.0
    for row in loop["per_process"]:
        assert row["timed_wall_s"] >= 1.0 and row["repeats"] > 1
        assert row["jax"]["env"] == "cpu"
    # an update is n_envs x n_steps env-steps; the rollout is a part of it
    assert ppo["env_steps_per_update"] == 4 * 8
    assert ppo["env_steps_per_s"] == pytest.approx(32 / ppo["s_per_update"])
    assert ppo["rollout_s"] == pytest.approx(ppo["s_per_update"] - ppo["learn_s"])
    assert ppo["max_vehicles"] == 8
    assert _positive(ppo["cpu_utilisation"]) and _positive(ppo["compile_s"])
    # both policy rollouts drive the same window of the full scenario, all AVs
    assert t["penetration"] == 1.0 and t["policy"]["fresh"]
    assert t["window_s"] == pytest.approx([5.0, 10.0])
    assert loop["window_s"] == pytest.approx(t["window_s"])
    assert jp["batch"] == POLICY_BATCH
    assert jp["steps"] == loop["steps"] == 10
    assert jp["env_steps_per_s"] == pytest.approx(POLICY_BATCH * 10 / jp["wall_s"])
    assert jp["mean_vehicles"] > 0 and jp["av_share"] == 1.0
    assert jp["overflow"] == 0
    # one SUMO process per core, each driving AVs with the policy
    assert loop["processes"] == usable_cpus() == len(loop["per_process"])
    assert loop["env_steps_per_s"] == pytest.approx(
        sum(10 / row["wall_s"] for row in loop["per_process"])
    )
    assert loop["mean_vehicles"] > 0
    assert all(row["commands"] > 0 for row in loop["per_process"])
    assert 0 < loop["controller_share"] < 1
    text = format_benchmark(result)
    assert "| PPO training (rollout + update) |" in text
    assert f"| SUMO in the loop, {loop['processes']} processes |" in text
    assert f"PPO / SUMO in the loop: {t['ppo_vs_sumo_in_the_loop']:.2f}x" in text
    assert f"CPU-second {t['ppo_vs_sumo_in_the_loop_per_cpu_s']:.2f}x" in text
    assert "freshly initialised" in text


@pytest.mark.parametrize(
    "kwargs",
    [
        {"batches": ()},
        {"batches": (0,)},
        {"sim_seconds": 0.0},
        {"max_vehicles": 0},
        {"slot_sizes": (16, 2.5)},
        {"sumo_processes": 0},
        {"policy": "policy.npz"},  # a policy without a training config
    ],
)
def test_bad_arguments_fail_before_running(kwargs: dict[str, Any]) -> None:
    with pytest.raises(ValueError):
        run_benchmark(small_config(), progress=False, **kwargs)


def test_batch_schedules_stack_the_seeds_schedules() -> None:
    cfg = small_config(n_vehicles=40, duration_s=60.0)
    env, _ = make(cfg, max_vehicles=8)
    batch = batch_schedules(env, 3, seed=5)
    for i in range(3):
        one = env.schedule_from_numpy(make_schedule(cfg, seed=5 + i))
        for name in ("depart_s", "route", "origin", "speed_factor", "is_av"):
            got, want = getattr(batch, name)[i], getattr(one, name)
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_bare_ring_keeps_its_vehicles_apart() -> None:
    # the yardstick is a working car-following step: from a uniform start no
    # vehicle drives into the one ahead, and speeds stay within [0, V0]
    m = 8
    pos = jnp.arange(m, dtype=jnp.float32) * (bare_ring.RING_M / m)
    state = (pos, jnp.full(m, 10.0), jnp.arange(m) % 2 == 0)
    step = jax.jit(lambda s: bare_ring.bare_step(s, 0.5, 2))
    for _ in range(200):
        state = step(state)
        p, v, active = (np.asarray(x) for x in state)
        on = np.sort(p[active] % bare_ring.RING_M)
        gaps = np.diff(np.append(on, on[0] + bare_ring.RING_M))
        assert np.all(gaps >= bare_ring.LENGTH_M), gaps
        assert np.all((v >= 0) & (v <= bare_ring.V0 + 1e-4))
        assert np.all(v[~active] == 0)


def test_bare_ring_rejects_a_bad_occupancy() -> None:
    with pytest.raises(ValueError, match="occupancy"):
        bare_ring.measure_bare_ring(8, 2, occupancy=0.0, steps=2, dt=0.5, n_substeps=2)


def test_a_missing_policy_fails_before_running(tmp_path: Any) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        run_benchmark(
            small_config(), progress=False, policy=tmp_path / "none.npz",
            training=load_ppo_config("ppo_milan").replace(**TINY_PPO),
        )  # fmt: skip


def test_measure_training_rejects_bad_numbers() -> None:
    from jaxround.apps.bench.training import measure_training

    cfg = load_ppo_config("ppo_milan").replace(**TINY_PPO)
    for kwargs in ({"updates": 0}, {"policy_batch": 0}, {"penetration": 1.5},
                   {"policy_seconds": 0.0}, {"sumo_processes": 0}):  # fmt: skip
        with pytest.raises(ValueError):
            measure_training(cfg, progress=False, **kwargs)
