"""The speed a user of `jaxround` would get: PPO training, and an exported
policy driving the AVs in JAX and in SUMO, in env-steps per second.

    result = measure_training(load_ppo_config("ppo_milan"))
    result["ppo_vs_sumo_in_the_loop"]

An env-step is one step of dt of one roundabout (a roundabout-step). Three
figures, taken one after the other in this one call:

- **PPO training**: whole updates (rollout of ``n_envs`` roundabouts over
  ``n_steps`` steps, GAE, the epochs of minibatches) of the training config,
  the jitted functions `jaxround train` calls, after the first update
  (compilation) and an untimed warm-up update;
  ``n_envs * n_steps`` env-steps per update. The rollout alone is compiled
  and timed too, so the split rollout / learning (update minus rollout) and
  the cores each keeps busy (CPU seconds per wall second) are reported.
- **JAX policy rollout**: the exported policy's deterministic action
  (`agents.common.evaluation.switched_policy`, as `jaxround evaluate` runs
  it) and the environment's step, ``jit(vmap(scan))`` over B roundabouts of
  the full scenario at one AV share, timed over [S, 2S) after an untimed
  warm-up over [0, S) (`jaxround.apps.bench.policy_windows`).
- **SUMO in the loop**: the same policy driving SUMO's AVs through the
  libsumo controller (`sumo_export.controller.PolicyController`), one
  process per usable core at once, the same window
  (`jaxround.apps.bench.policy_windows`); env-steps/s summed over processes.

Without a trained policy (``policy=None``) a freshly initialised network of
the training config is exported to a temporary folder: its actions are
meaningless, its cost is a trained one's (same layout).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from agents.common import networks
from agents.common.config import PPOConfig
from agents.common.evaluation import with_observer
from agents.common.export import (
    check_scenario,
    export_policy,
    load_policy,
    policy_layout,
)
from agents.ppo.train import Trainer
from agents.run.algorithms import compiled_trainer
from jaxround.apps.bench.policy_windows import (
    measure_jax_policy,
    measure_sumo_in_the_loop,
)
from jaxround.apps.bench.sumo_timing import usable_cpus
from jaxround.scenario.config import ConfigError, ScenarioConfig

#: Updates timed after the compiling one and the warm-up ones.
DEFAULT_UPDATES = 3
#: Untimed updates after the compiling one (caches, allocator).
WARMUP_UPDATES = 1
#: Roundabouts of the JAX policy rollout.
DEFAULT_POLICY_BATCH = 256
#: Warm-up and timed window of the policy rollouts, simulated seconds: the
#: window is [S, 2S) of an episode of the full scenario.
DEFAULT_POLICY_SECONDS = 150.0
#: AV share of the policy rollouts: every vehicle is an AV the policy drives.
DEFAULT_PENETRATION = 1.0

WHAT_IS_TIMED = (
    "PPO: whole jitted updates (rollout, GAE, epochs x minibatches of Adam) "
    "until the metrics are on the host, after the compiling update and "
    f"{WARMUP_UPDATES} warm-up update; rollout alone: the jitted rollout of the "
    "same runner. JAX policy: one jit(vmap(scan(policy + step_env))) call over "
    "the window after an untimed warm-up window. SUMO in the loop: per step "
    "simulation.step(), the controller (read, observe, policy, command) and "
    "vehicle.getIDCount(), after the warm-up window with the controller, in one "
    "process per core at once. Not timed: compilation, scenario files, "
    "libsumo.start, the policy's export."
)


def measure_training(
    config: PPOConfig,
    *,
    policy: str | Path | None = None,
    updates: int = DEFAULT_UPDATES,
    policy_batch: int = DEFAULT_POLICY_BATCH,
    policy_seconds: float = DEFAULT_POLICY_SECONDS,
    penetration: float = DEFAULT_PENETRATION,
    sumo_processes: int | None = None,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """PPO training, the JAX policy rollout and SUMO in the loop, in env-steps/s.

    See the module docstring for what is timed.

    Args:
        config: the PPO config timed (its scenario, full demand, is the one
            the policies drive).
        policy: an exported policy (``.npz``, ``.json``, stem or folder)
            trained on the config's roads and drivers; None: a freshly
            initialised network of `config`.
        updates: PPO updates timed.
        policy_batch: roundabouts B of the JAX policy rollout.
        policy_seconds: simulated seconds S of the policy rollouts' warm-up
            and timed window [S, 2S).
        penetration: AV share of the policy rollouts' schedules.
        sumo_processes: SUMO processes at once; default one per usable core.
        seed: schedule seed of the policy rollouts (roundabout i and SUMO
            process i run seed + i).
        progress: notes on stderr.

    Returns:
        ``{"ppo_env_steps_per_s", "jax_policy_env_steps_per_s",
        "sumo_in_the_loop_env_steps_per_s", "ppo_vs_sumo_in_the_loop",
        "ppo_vs_sumo_in_the_loop_per_cpu_s" (env-steps per CPU second of
        the timed processes: what a busy machine moves least),
        "jax_policy_vs_sumo_in_the_loop", "ppo": {...}, "jax_policy": {...},
        "sumo_in_the_loop": {...}, "policy": {"path", "fresh", "observer",
        "action"}, "penetration", "window_s", "what_is_timed", ...}``.

    Raises:
        ValueError: a bad number, or a policy that does not fit the scenario.
        FileNotFoundError: the policy's files are missing.
    """
    if not isinstance(config, PPOConfig):
        raise ValueError(f"training config: a PPOConfig, not {type(config).__name__}")
    updates = _positive_int(updates, "updates")
    policy_batch = _positive_int(policy_batch, "policy_batch")
    if sumo_processes is None:
        sumo_processes = usable_cpus()
    sumo_processes = _positive_int(sumo_processes, "sumo_processes")
    if not 0.0 <= penetration <= 1.0:
        raise ValueError(f"penetration: {penetration!r}, expected a share in [0, 1]")
    if not policy_seconds > 0:
        raise ValueError(f"policy_seconds: {policy_seconds!r}, expected > 0")

    def note(text: str) -> None:
        if progress:
            tqdm.write(f"bench: {text}", file=sys.stderr)

    started = time.perf_counter()
    try:
        trainer, init, update = compiled_trainer(config)
    except ConfigError as err:
        raise ValueError(f"training config: {err}") from None
    note(
        f"PPO: {config.n_envs} roundabouts x {config.n_steps} steps per update, "
        f"M = {trainer.env.max_vehicles}; compiling, then {updates} updates timed"
    )
    ppo = measure_ppo(trainer, init, update, updates)
    with tempfile.TemporaryDirectory(prefix="jaxround-bench-policy-") as tmp:
        path = policy if policy is not None else fresh_policy(trainer, Path(tmp))
        arrays, layout = load_policy(path)
        scenario = with_observer(config.base_scenario(), layout.observer, layout.action)
        check_scenario(layout, scenario)
        scenario = _with_penetration(scenario, penetration)
        note(
            f"JAX policy rollout: {policy_batch} roundabouts at {penetration:.0%} AVs, "
            f"simulated {policy_seconds:g}-{2 * policy_seconds:g} s"
        )
        jax_policy = measure_jax_policy(
            scenario, arrays, layout, batch=policy_batch, seconds=policy_seconds,
            seed=seed,
        )  # fmt: skip
        note(f"SUMO in the loop: the same policy, {sumo_processes} processes at once")
        sumo = measure_sumo_in_the_loop(
            scenario, str(path), processes=sumo_processes, seconds=policy_seconds,
            seed=seed,
        )  # fmt: skip
    in_loop = sumo["env_steps_per_s"]
    return {
        "ppo_env_steps_per_s": ppo["env_steps_per_s"],
        "jax_policy_env_steps_per_s": jax_policy["env_steps_per_s"],
        "sumo_in_the_loop_env_steps_per_s": in_loop,
        "ppo_vs_sumo_in_the_loop": ppo["env_steps_per_s"] / in_loop,
        "ppo_vs_sumo_in_the_loop_per_cpu_s": ppo["env_steps_per_cpu_s"]
        / sumo["env_steps_per_cpu_s"],
        "jax_policy_vs_sumo_in_the_loop": jax_policy["env_steps_per_s"] / in_loop,
        "ppo": ppo,
        "jax_policy": jax_policy,
        "sumo_in_the_loop": sumo,
        "policy": {
            "path": None if policy is None else str(policy),
            "fresh": policy is None,
            "observer": layout.observer,
            "action": layout.action,
        },
        "training_config": config.to_dict(),
        "scenario": scenario.name,
        "penetration": penetration,
        "window_s": [jax_policy["window_s"][0], jax_policy["window_s"][1]],
        "what_is_timed": WHAT_IS_TIMED,
        "wall_s": time.perf_counter() - started,
    }


def fresh_policy(trainer: Trainer, folder: Path) -> Path:
    """Export a freshly initialised network of `trainer` (its config's seed)
    into `folder`; the ``.npz`` path."""
    params = networks.init_params(
        trainer.network,
        jax.random.PRNGKey(trainer.config.seed),
        trainer.obs_size,
        trainer.env.max_vehicles,
    )
    npz, _ = export_policy(jax.device_get(params), policy_layout(trainer), folder)
    return npz


def measure_ppo(
    trainer: Trainer, init: Callable[..., Any], update: Callable[..., Any], updates: int
) -> dict[str, Any]:
    """Time `updates` whole PPO updates, each followed by the rollout alone
    from the same runner.

    Args:
        trainer: the PPO trainer.
        init, update: its jitted ``init(key)`` and one update (as
            `agents.run.algorithms.compiled_trainer` gives them, the functions
            `jaxround train` calls).
        updates: updates timed.

    Returns:
        ``{"env_steps_per_s", "env_steps_per_cpu_s", "s_per_update",
        "rollout_s", "learn_s" (update minus rollout), "rollout_share",
        "cpu_utilisation", "rollout_cpu_utilisation", "learn_cpu_utilisation",
        "compile_s", "updates", "n_envs", "n_steps", "max_vehicles",
        "env_steps_per_update", "devices"}``; times are medians, CPU use is
        CPU seconds of this process per wall second over the timed calls.
    """
    cfg = trainer.config
    t0 = time.perf_counter()
    runner = jax.block_until_ready(init(jax.random.PRNGKey(cfg.seed)))
    rollout = jax.jit(trainer.rollout)
    runner = jax.block_until_ready(update(runner))[0]
    jax.block_until_ready(rollout(runner))
    compile_s = time.perf_counter() - t0
    for _ in range(WARMUP_UPDATES):
        runner = jax.block_until_ready(update(runner))[0]
    upd_walls, upd_cpus, roll_walls, roll_cpus = [], [], [], []
    for _ in range(updates):
        start = runner
        (runner, _), wall, cpu = _timed(update, runner)
        upd_walls.append(wall)
        upd_cpus.append(cpu)
        _, wall, cpu = _timed(rollout, start)
        roll_walls.append(wall)
        roll_cpus.append(cpu)
    s_update, s_roll = float(np.median(upd_walls)), float(np.median(roll_walls))
    learn_wall = sum(upd_walls) - sum(roll_walls)
    learn_cpu = sum(upd_cpus) - sum(roll_cpus)
    n = cfg.env_steps_per_update
    return {
        "env_steps_per_s": n / s_update,
        "env_steps_per_cpu_s": n * updates / max(sum(upd_cpus), 1e-9),
        "rollout_env_steps_per_s": n / s_roll,
        "s_per_update": s_update,
        "rollout_s": s_roll,
        "learn_s": s_update - s_roll,
        "rollout_share": s_roll / s_update,
        "cpu_utilisation": sum(upd_cpus) / sum(upd_walls),
        "rollout_cpu_utilisation": sum(roll_cpus) / sum(roll_walls),
        "learn_cpu_utilisation": learn_cpu / learn_wall if learn_wall > 0 else None,
        "compile_s": compile_s,
        "updates": updates,
        "n_envs": cfg.n_envs,
        "n_steps": cfg.n_steps,
        "max_vehicles": trainer.env.max_vehicles,
        "env_steps_per_update": n,
        "devices": len(jax.local_devices()),
    }


def _timed(fn: Callable[..., Any], *args: Any) -> tuple[Any, float, float]:
    """(fn(*args) once ready, wall seconds, CPU seconds of this process)."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t0, time.process_time() - c0


def _with_penetration(cfg: ScenarioConfig, share: float) -> ScenarioConfig:
    from jaxround.scenario.config import config_from_dict

    d = cfg.to_dict()
    d["simulation"]["penetration"] = float(share)
    return config_from_dict(d)


def _positive_int(x: Any, name: str) -> int:
    if isinstance(x, bool) or int(x) != x or x < 1:
        raise ValueError(f"{name}: {x!r}, expected a positive integer")
    return int(x)


__all__ = ["WHAT_IS_TIMED", "fresh_policy", "measure_ppo", "measure_training"]
