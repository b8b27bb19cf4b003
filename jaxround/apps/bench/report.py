"""The tables of `jaxround.apps.bench`'s result, and what machine and code it ran on."""

from __future__ import annotations

import os
import platform
import subprocess
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import jax


def format_benchmark(result: dict[str, Any]) -> str:
    """A Markdown summary of `run_benchmark`'s result: two tables and the ratio."""
    sumo_rate = result["sumo_vehicle_steps_per_s"]
    sumo = result.get("sumo", {})
    window = result.get("window_s", [result["sim_seconds"], 2 * result["sim_seconds"]])
    lines = [
        f"Scenario `{result.get('scenario', '?')}`: simulated window "
        f"{_num(window[0])}-{_num(window[1])} s after a warm-up of "
        f"{_num(window[0])} s, M = {result.get('max_vehicles', '?')} slots.",
        "",
        "| simulator | batch | vehicle-steps/s | vs SUMO | vehicle-steps/CPU-s "
        "| roundabout-steps/s | mean vehicles | CPU use | compile (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| SUMO (libsumo) | 1 | {sumo_rate:,.0f} | 1.00 "
        f"| {_fmt(sumo.get('vehicle_steps_per_cpu_s'), ',.0f')} "
        f"| {_fmt(sumo.get('steps_per_s'), ',.0f')} "
        f"| {_fmt(sumo.get('mean_vehicles'), '.1f')} "
        f"| {_fmt(sumo.get('cpu_utilisation'), '.2f')} | - |",
    ]
    parallel = result.get("sumo_parallel")
    if parallel:
        n = parallel["processes"]
        lines.append(
            f"| SUMO (libsumo), {n} processes | {n} "
            f"| {parallel['vehicle_steps_per_s']:,.0f} "
            f"| {parallel['vehicle_steps_per_s'] / sumo_rate:.2f} "
            f"| {_fmt(parallel.get('vehicle_steps_per_cpu_s'), ',.0f')} | - "
            f"| {_fmt(parallel.get('mean_vehicles'), '.1f')} | - | - |"
        )
    for row in result["jax"]:
        lines.append(
            f"| JAX | {row['batch']} | {row['vehicle_steps_per_s']:,.0f} "
            f"| {row['vehicle_steps_per_s'] / sumo_rate:.2f} "
            f"| {_fmt(row.get('vehicle_steps_per_cpu_s'), ',.0f')} "
            f"| {row['steps_per_s']:,.0f} "
            f"| {_fmt(row.get('mean_vehicles'), '.1f')} "
            f"| {_fmt(row.get('cpu_utilisation'), '.2f')} "
            f"| {row['compile_s']:.1f} |"
        )
    best = max(result["jax"], key=lambda row: row["vehicle_steps_per_s"])
    lines += ["", _ratio_line(result, best)]
    bare = result.get("bare_ring")
    if bare:
        lines += [
            "",
            "| yardstick (batch "
            f"{bare['batch']}) | vehicle-steps/s | vs SUMO | us/step/roundabout "
            "| flops/step/roundabout | GFLOP/s |",
            "|---|---:|---:|---:|---:|---:|",
            _work_row("JAX environment", best),
            _work_row("bare IDM ring", bare),
            "",
            "Bare IDM ring (`jaxround.apps.bare_ring`): the same slots and occupancy, "
            "one pairwise leader search and one IDM update per step, nothing else: "
            "the ceiling of a car-following step on this machine. Flops: XLA's "
            "cost analysis of the compiled program.",
        ]
    if result.get("slots"):
        batch = result["slots"][0].get("batch", result.get("slot_batch", "?"))
        lines += [
            "",
            f"Cost of one step against the slot count M (batch {batch}):",
            "",
            "| max_vehicles | us/step/roundabout | us/vehicle-step "
            "| mean vehicles | CPU use | compile (s) |",
            "|---:|---:|---:|---:|---:|---:|",
        ]
        for row in result["slots"]:
            lines.append(
                f"| {row['max_vehicles']} | {row['us_per_step_per_roundabout']:,.1f} "
                f"| {_fmt(row.get('us_per_vehicle_step'), ',.1f')} "
                f"| {_fmt(row.get('mean_vehicles'), '.1f')} "
                f"| {_fmt(row.get('cpu_utilisation'), '.2f')} "
                f"| {_fmt(row.get('compile_s'), '.1f')} |"
            )
    if result.get("training"):
        lines += ["", *format_training(result["training"])]
    machine = result.get("machine", {})
    if machine:
        cpu = machine.get("cpu_model") or machine.get("machine", "?")
        devices = ", ".join(machine.get("jax_devices", []))
        lines += [
            "",
            f"Machine: {cpu}, {machine.get('cpu_count', '?')} CPUs, "
            f"JAX {machine.get('jax_version')} ({machine.get('jax_backend')}: "
            f"{devices}), {machine.get('sumo_version')}, {machine.get('date')}; "
            f"load average {machine.get('load_average_before')} before the run, "
            f"{machine.get('load_average')} after.",
            "",
            "CPU use: CPU seconds of the timing process per wall second (XLA may "
            "use several threads; SUMO uses one).",
        ]
    code = result.get("code", {})
    if code.get("commit"):
        changes = " with local changes" if code.get("local_changes") else ""
        lines += ["", f"Code: commit {code['commit'][:12]}{changes}."]
    return "\n".join(lines) + "\n"


def format_training(t: dict[str, Any]) -> list[str]:
    """The lines of `jaxround.apps.bench.training.measure_training`'s result:
    PPO, the JAX policy rollout and SUMO in the loop in env-steps/s."""
    ppo, jp, loop = t["ppo"], t["jax_policy"], t["sumo_in_the_loop"]
    rollout_ratio = ppo["rollout_env_steps_per_s"] / loop["env_steps_per_s"]
    window = t["window_s"]
    policy = (
        "a freshly initialised network (throughput only)"
        if t["policy"]["fresh"]
        else f"`{t['policy']['path']}`"
    )
    return [
        "Training and policy rollouts, in env-steps/s (one env-step: one dt step "
        "of one roundabout):",
        "",
        "| what | env-steps/s | vs SUMO in the loop | vehicle-steps/s "
        "| roundabouts | M | CPU use | compile (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        f"| PPO training (rollout + update) | {ppo['env_steps_per_s']:,.0f} "
        f"| {t['ppo_vs_sumo_in_the_loop']:.2f} | - | {ppo['n_envs']} "
        f"| {ppo['max_vehicles']} | {ppo['cpu_utilisation']:.2f} "
        f"| {ppo['compile_s']:.1f} |",
        f"| PPO rollout alone | {ppo['rollout_env_steps_per_s']:,.0f} "
        f"| {rollout_ratio:.2f} | - | {ppo['n_envs']} | {ppo['max_vehicles']} "
        f"| {ppo['rollout_cpu_utilisation']:.2f} | - |",
        f"| JAX, exported policy | {jp['env_steps_per_s']:,.0f} "
        f"| {t['jax_policy_vs_sumo_in_the_loop']:.2f} "
        f"| {jp['vehicle_steps_per_s']:,.0f} | {jp['batch']} | {jp['max_vehicles']} "
        f"| {jp['cpu_utilisation']:.2f} | {jp['compile_s']:.1f} |",
        f"| SUMO in the loop, {loop['processes']} processes "
        f"| {loop['env_steps_per_s']:,.0f} | 1.00 "
        f"| {loop['vehicle_steps_per_s']:,.0f} | {loop['processes']} | - | - | - |",
        "",
        f"PPO (`{t['training_config'].get('scenario')}`, {ppo['n_envs']} x "
        f"{ppo['n_steps']} env-steps per update): {ppo['s_per_update']:.2f} s per "
        f"update, rollout {ppo['rollout_s']:.2f} s (CPU use "
        f"{ppo['rollout_cpu_utilisation']:.2f}), learning {ppo['learn_s']:.2f} s "
        f"(CPU use {_fmt(ppo.get('learn_cpu_utilisation'), '.2f')}); "
        f"**PPO / SUMO in the loop: {t['ppo_vs_sumo_in_the_loop']:.2f}x**, per "
        f"CPU-second {t['ppo_vs_sumo_in_the_loop_per_cpu_s']:.2f}x.",
        "",
        f"Policy rollouts: {policy}, {t['penetration']:.0%} AVs, simulated window "
        f"{_num(window[0])}-{_num(window[1])} s after a warm-up with the policy "
        f"driving; SUMO's controller took {loop['controller_share']:.0%} of its "
        "timed wall time.",
    ]


# ------------------------------------------------------------------ SUMO


def _ratio_line(result: dict[str, Any], best: dict[str, Any]) -> str:
    """The headline: the best batch against SUMO, per wall and CPU second and
    against SUMO in one process per core."""
    text = (
        f"Best JAX / SUMO: **{result['best_ratio_vs_sumo']:.2f}x** "
        f"(batch {best['batch']})"
    )
    per_cpu = result.get("best_ratio_vs_sumo_per_cpu_s")
    if per_cpu is not None:
        text += f"; per CPU-second {per_cpu:.2f}x"
    parallel = result.get("sumo_parallel")
    if parallel:
        text += (
            f"; against SUMO in {parallel['processes']} processes "
            f"{result['best_ratio_vs_sumo_parallel']:.2f}x"
        )
    spread = result.get("sumo", {}).get("spread")
    if spread:
        sumo = result["sumo"]
        text += (
            f" SUMO in one process: {sumo['repeats']} repeats of the window in "
            f"{sumo['timed_wall_s']:.2f} s, {spread['p10']:,.0f} to "
            f"{spread['p90']:,.0f} vehicle-steps/s (10th to 90th percentile)"
        )
    device = result.get("device")
    if device:
        text += f". Device: {device['count']} x {device['kind']} ({device['platform']})"
    return text + "."


def machine_info(sumo_version: str | None = None) -> dict[str, Any]:
    """Platform, CPUs, memory, Python, JAX (backend, devices) and SUMO versions."""
    try:
        memory_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        memory_gib = None
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": usable,
        "memory_gib": None if memory_gib is None else round(memory_gib, 1),
        "python": platform.python_version(),
        "jax_version": jax.__version__,
        "jaxlib_version": _package_version("jaxlib"),
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "sumo_version": sumo_version,
        "date": datetime.now(UTC).date().isoformat(),
        "load_average": load_average(),
    }


def code_version() -> dict[str, Any]:
    """jaxround's version and, in a git checkout, its commit and whether the
    package sources differ from it (read-only git commands)."""
    info: dict[str, Any] = {"jaxround": _package_version("jaxround")}
    root = Path(__file__).resolve().parents[3]  # the checkout (or site-packages)
    git = ["git", "-C", str(root)]
    try:
        head = subprocess.run(
            [*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if head.returncode == 0:
            info["commit"] = head.stdout.strip()
            diff = subprocess.run(
                [*git, "diff", "--quiet", "HEAD", "--", "jaxround", "sumo_export"],
                capture_output=True,
                timeout=10,
            )
            info["local_changes"] = diff.returncode != 0
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def _package_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (other work on a shared machine)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def _work_row(name: str, row: dict[str, Any]) -> str:
    """A row of the yardstick table: speed and XLA's flop count of one program."""
    return (
        f"| {name} | {row['vehicle_steps_per_s']:,.0f} "
        f"| {_fmt(row.get('ratio_vs_sumo'), '.2f')} "
        f"| {row['us_per_step_per_roundabout']:,.1f} "
        f"| {_fmt(row.get('flops_per_roundabout_step'), ',.0f')} "
        f"| {_fmt(row.get('gflops_per_s'), '.1f')} |"
    )


def _num(x: float) -> str:
    return f"{x:g}"


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)
