"""An episode of the JAX roundabout as a movie: run it, keep its states, draw them.

    states = rollout_states(env, params, key, n_steps=240, every=2)
    animate(env, states, "episode.gif", fps=10)

The pictures themselves are `jaxround.analysis.render`'s.
Shapes: M vehicle slots, T frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp

from jaxround.analysis.render import draw_network, draw_vehicles, n_frames, state_at
from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState, Schedule
from jaxround.envs.rollout import Policy, uncontrolled_policy
from jaxround.envs.roundabout import RoundaboutEnv, make

if TYPE_CHECKING:
    from matplotlib.animation import AbstractMovieWriter


def movie_writer(path: str | Path, fps: float = 10.0) -> AbstractMovieWriter:
    """The matplotlib writer for `path`: Pillow for ``.gif``, ffmpeg for ``.mp4``.

    Raises:
        ValueError: an unknown suffix, or ``.mp4`` without ffmpeg on the PATH.
    """
    from matplotlib import animation

    suffix = Path(path).suffix.lower()
    if suffix == ".gif":
        return animation.PillowWriter(fps=fps)
    if suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ValueError(f"{path}: an .mp4 needs ffmpeg on the PATH; write a .gif")
        return animation.FFMpegWriter(fps=fps)
    raise ValueError(f"{path}: write a .gif or an .mp4")


def animate(
    env: RoundaboutEnv,
    states: EnvState,
    path: str | Path,
    fps: float = 10.0,
    dpi: float = 90.0,
    figsize: tuple[float, float] = (4.0, 4.0),
) -> Path:
    """Write a trajectory of states as an animated GIF, or MP4 with ffmpeg.

    Args:
        env: the environment the states come from.
        states: stacked states, per-vehicle fields (T, M) (e.g. from
            `rollout_states`); one frame per state.
        path: the file to write; ``.gif`` (Pillow) or ``.mp4`` (ffmpeg).
        fps: frames per second of the animation.
        dpi: resolution; the image is ``figsize * dpi`` pixels.
        figsize: figure size, inches.

    Returns:
        The path written.

    Raises:
        ValueError: an unknown suffix, or ``.mp4`` without ffmpeg (`movie_writer`).
    """
    from matplotlib.figure import Figure

    path = Path(path)
    writer = movie_writer(path, fps)
    host = jax.device_get(states)
    frames = n_frames(host)
    fig = Figure(figsize=figsize, layout="constrained")
    art = draw_network(env, fig.add_subplot())
    path.parent.mkdir(parents=True, exist_ok=True)
    with writer.saving(fig, str(path), dpi):
        for i in range(frames):
            draw_vehicles(env, art, state_at(host, i))
            writer.grab_frame()
    return path


def rollout_states(
    env: RoundaboutEnv,
    params: EnvParams,
    key: jax.Array,
    n_steps: int,
    policy: Policy | None = None,
    every: int = 2,
    schedule: Schedule | None = None,
) -> EnvState:
    """Run an episode and keep every `every`-th state, for `animate`.

    Starts from ``env.reset`` (a schedule drawn with `key`) or, if given, from
    ``env.reset_to_schedule(schedule)``, and steps with ``env.step_env`` (no
    automatic reset) as `jaxround.envs.rollout.run_episode` does, in one jitted
    scan (compiled on each call).

    Args:
        env: the environment.
        params: traced parameters.
        key: PRNG key of the reset and the policy.
        n_steps: steps to run; ``n_steps // every * every`` are run.
        policy: ``policy(obs, state, key) -> action (M, 2)``; AVs drive their
            IDM vType if None (`uncontrolled_policy`).
        every: steps between kept states.
        schedule: the departure schedule (N,); drawn from `key` if None.

    Returns:
        The states after 0, every, 2 * every, ... steps, stacked: per-vehicle
        fields (T, M) with T = n_steps // every + 1.
    """
    if every < 1 or n_steps < every:
        raise ValueError(
            f"n_steps {n_steps}, every {every}: need n_steps >= every >= 1"
        )
    policy = uncontrolled_policy(env) if policy is None else policy
    n_kept = n_steps // every

    def run(params: EnvParams, key: jax.Array, schedule: Schedule | None) -> EnvState:
        k_reset, k_run = jax.random.split(key)
        if schedule is None:
            obs, state = env.reset(k_reset, params)
        else:
            obs, state = env.reset_to_schedule(schedule, params)

        def step(carry: tuple[jax.Array, EnvState], step_key: jax.Array) -> Any:
            obs, state = carry
            k_act, k_env = jax.random.split(step_key)
            action = policy(obs, state, k_act)
            obs, state, _, _, _ = env.step_env(k_env, state, action, params)
            return (obs, state), None

        def keep(carry: tuple[jax.Array, EnvState], frame_key: jax.Array) -> Any:
            carry, _ = jax.lax.scan(step, carry, jax.random.split(frame_key, every))
            return carry, carry[1]

        _, kept = jax.lax.scan(keep, (obs, state), jax.random.split(k_run, n_kept))
        return jax.tree.map(
            lambda first, rest: jnp.concatenate([jnp.expand_dims(first, 0), rest]),
            state,
            kept,
        )

    return jax.jit(run)(params, key, schedule)


def render_rollout(
    out: str | Path,
    scenario: str | Path = "milan",
    seconds: float = 120.0,
    every: int = 2,
    penetration: float | None = None,
    seed: int = 0,
    fps: float = 10.0,
    max_vehicles: int | None = None,
) -> Path:
    """Animate the first `seconds` of an episode of a scenario (for the CLI).

    Args:
        out: the ``.gif`` or ``.mp4`` to write.
        scenario: built-in name or YAML path (as `jaxround.make`).
        seconds: simulated time to show.
        every: steps between frames.
        penetration: AV share 0-1; the config's if None.
        seed: PRNG seed of the drawn schedule.
        fps: frames per second.
        max_vehicles: vehicle slots M; None: the config's, else the road's.

    Returns:
        The path written.

    Raises:
        ValueError: `out` is neither ``.gif`` nor ``.mp4`` (or ffmpeg is missing).
    """
    movie_writer(out, fps)  # an unusable file name fails before the episode runs
    env, params = make(scenario, max_vehicles=max_vehicles)
    if penetration is not None:
        params = params.with_penetration(penetration)
    n_steps = max(every, int(round(seconds / env.dt)))
    states = rollout_states(env, params, jax.random.PRNGKey(seed), n_steps, every=every)
    return animate(env, states, out, fps=fps)
