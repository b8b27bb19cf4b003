"""What the policy does differently: its AVs beside uncontrolled AVs.

`policy_behaviour` runs one schedule in JAX twice, the AVs driven by the
exported policy and by their vType alone, and collects for every AV step its
distance to the yield line, its speed and (for an assertiveness policy) the
headway and impatience it chose. `plot_behaviour` draws speed against the
distance to the yield line for both, and the policy's choice along the way:
``behaviour.png`` in the main job's folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.common.evaluation import switched_policy, with_observer
from agents.common.export import load_policy
from jaxround.envs.assertiveness import (
    assertive_impatience,
    assertive_tau,
    assertiveness,
)
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import make_schedule

#: Distance bins to the yield line (m; negative: past it, in the ring).
BINS = np.arange(-30.0, 46.0, 5.0)


def policy_behaviour(
    policy_path: str | Path,
    cfg: ScenarioConfig,
    penetration: float = 1.0,
    seed: int = 0,
) -> dict[str, dict[str, np.ndarray]]:
    """Per AV step, with the policy and uncontrolled, on one schedule.

    Returns:
        ``{"policy" | "uncontrolled": {"to_line": m, "speed": m/s,
        "tau": s, "impatience": -}}``, float (S,) each over the AV steps
        (tau and impatience are the vType's for uncontrolled AVs).
    """
    arrays, layout = load_policy(policy_path)
    cfg = with_observer(cfg, layout.observer, layout.action)
    env, params = make(cfg)
    schedule = env.schedule_from_numpy(
        make_schedule(cfg, seed=seed, penetration=penetration)
    )
    weights = {k: jnp.asarray(v) for k, v in arrays.items()}

    def episode(carry: Any, keys: jax.Array, use_policy: jax.Array) -> Any:
        act = switched_policy(weights, layout, use_policy)

        def body(carry: Any, key: jax.Array) -> tuple[Any, Any]:
            obs, state = carry
            action = act(obs, state, key)
            obs, nxt, _, _, _ = env.step_env(key, state, action, params)
            agent = state.active & state.is_av
            to_line = env.net.yield_offset[state.route] - state.pos
            return (obs, nxt), (agent, to_line, nxt.speed, action[:, 0])

        return jax.lax.scan(body, carry, keys)[1]

    # one program for both drivers: the switch is an argument, not a constant
    run = jax.jit(episode)
    start = env.reset_to_schedule(schedule, params)
    keys = jax.random.split(jax.random.PRNGKey(seed), env.episode_steps)
    out: dict[str, dict[str, np.ndarray]] = {}
    for driver in ("policy", "uncontrolled"):
        agent, to_line, speed, raw = run(start, keys, jnp.bool_(driver == "policy"))
        agent = np.asarray(agent)
        u = np.asarray(assertiveness(raw)) if layout.action == "assertiveness" else 0
        av = cfg.drivers.av
        u = np.broadcast_to(u, agent.shape)
        if driver == "uncontrolled":
            u = np.zeros_like(agent, np.float32)
        out[driver] = {
            "to_line": np.asarray(to_line)[agent],
            "speed": np.asarray(speed)[agent],
            "tau": np.asarray(assertive_tau(av.tau, u, cfg.safety.min_av_tau_s))[agent],
            "impatience": np.asarray(assertive_impatience(av.impatience, u))[agent],
        }
    return out


def binned(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of y in the `BINS` of x: (bin centres, means; NaN where empty)."""
    idx = np.digitize(x, BINS)
    centres = 0.5 * (BINS[1:] + BINS[:-1])
    means = np.array(
        [
            y[idx == i].mean() if np.any(idx == i) else np.nan
            for i in range(1, len(BINS))
        ]
    )
    return centres, means


def plot_behaviour(
    behaviour: dict[str, dict[str, np.ndarray]], path: Path, title: str
) -> None:
    """Speed, headway and impatience against the distance to the yield line."""
    from jaxround.analysis.plots import plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    style = {"policy": ("tab:blue", "-"), "uncontrolled": ("tab:gray", "--")}
    panels = (("speed", "mean speed (m/s)"), ("tau", "headway tau (s)"),
              ("impatience", "impatience"))  # fmt: skip
    for ax, (key, label) in zip(axes, panels, strict=True):
        for driver, data in behaviour.items():
            color, line = style[driver]
            x, y = binned(data["to_line"], data[key])
            ax.plot(x, y, line, color=color, marker=".", label=driver)
        ax.axvline(0.0, color="k", lw=0.6)
        ax.set_xlabel("distance to the yield line (m; < 0: past it)")
        ax.set_ylabel(label)
        ax.invert_xaxis()
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
