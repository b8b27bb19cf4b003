"""Pictures of the JAX roundabout: one state, an animated episode, vehicle counts.

    states = rollout_states(env, params, key, n_steps=240, every=2)
    render_state(env, state_at(states, -1))
    animate(env, states, "episode.gif", fps=10)

Lanes are drawn from the lane shapes of the compiled `.net.xml` (internal
junction lanes included), so the picture is SUMO's geometry. A vehicle is a
rectangle whose centre lies half a vehicle length behind its front bumper,
along its route, and whose heading is that of the chord from its back to its
front. AVs and human drivers wear the colours of their SUMO vTypes; a halting
vehicle (below 0.1 m/s) has a red outline; "+n" at the start of an approach
counts the vehicles that are due but still wait to be inserted.

matplotlib is imported inside the functions, so importing this module does not
choose a matplotlib backend.

Shapes: M vehicle slots, T frames, L lanes, G legs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.dynamics import HALTING_SPEED
from jaxround.env import RoundaboutEnv, make
from jaxround.network import CompiledNetwork
from jaxround.rollout import Policy, uncontrolled_policy
from jaxround.state import EnvParams, EnvState, Schedule

if TYPE_CHECKING:
    from matplotlib.animation import AbstractMovieWriter
    from matplotlib.axes import Axes
    from matplotlib.collections import PolyCollection
    from matplotlib.text import Text

#: The vTypes' colours in the SUMO route files (`sumo_export.scenario`), RGB 0-1.
AV_COLOR = (0 / 255, 160 / 255, 255 / 255)
HV_COLOR = (255 / 255, 200 / 255, 0 / 255)
#: Outline of a halting vehicle, and of the others.
HALTING_EDGE = "red"
MOVING_EDGE = "0.25"
#: SUMO's default lane width and passenger-car width (m).
LANE_WIDTH = 3.2
VEHICLE_WIDTH = 1.8
ROAD_COLOR = "0.78"
#: The `gid` of the vehicles' PolyCollection (one polygon per active slot).
VEHICLES_GID = "vehicles"


# ------------------------------------------------------------------ geometry


@dataclass(frozen=True)
class LaneGeometry:
    """Arc-length tables of the lane shapes, to place route positions in x, y.

    Attributes:
        network: the compiled network.
        cum: per lane, float (n_i,) arc length of the shape's points.
    """

    network: CompiledNetwork
    cum: tuple[np.ndarray, ...]

    @classmethod
    def from_network(cls, network: CompiledNetwork) -> LaneGeometry:
        cum = tuple(
            np.concatenate(
                [[0.0], np.cumsum(np.linalg.norm(np.diff(s, axis=0), axis=1))]
            )
            for s in network.lane_shapes
        )
        return cls(network, cum)

    def locate(
        self, route: np.ndarray, pos: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Lane and position on it of route positions (as `geometry.locate`).

        Args:
            route: int (M,) route index; pos: float (M,) position along it, m.

        Returns:
            (lane, pos_on_lane): int (M,), float (M,).
        """
        net = self.network
        starts = np.where(
            np.isnan(net.route_lane_start[route]), np.inf, net.route_lane_start[route]
        )  # (M, K)
        k = np.clip((starts <= pos[:, None]).sum(1) - 1, 0, starts.shape[1] - 1)
        rows = np.arange(route.shape[0])
        return net.route_lanes[route, k], pos - starts[rows, k]

    def points(self, route: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """x, y of route positions on the lane shapes, float (M, 2).

        A lane's length may differ from its shape's (SUMO scales internal
        lanes), so the position is mapped by its fraction of the lane.
        """
        lane, on_lane = self.locate(route, pos)
        xy = np.empty((route.shape[0], 2))
        for i, (ln, d) in enumerate(zip(lane, on_lane, strict=True)):
            shape, cum = self.network.lane_shapes[ln], self.cum[ln]
            frac = np.clip(d / max(self.network.lane_length[ln], 1e-9), 0.0, 1.0)
            s = frac * cum[-1]
            xy[i] = np.interp(s, cum, shape[:, 0]), np.interp(s, cum, shape[:, 1])
        return xy


def vehicle_boxes(
    env: RoundaboutEnv,
    route: np.ndarray,
    pos: np.ndarray,
    geometry: LaneGeometry | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where to draw vehicles: centre, heading and the four corners.

    Args:
        env: the environment (network, vehicle length).
        route: int (M,) route of each vehicle.
        pos: float (M,) front position along the route, m.
        geometry: `LaneGeometry` of `env.network`, built if None.

    Returns:
        (centre, heading, corners): float (M, 2) the point half a vehicle
        length behind the front, on the lane shape; float (M,) radians, of the
        chord from back to front; float (M, 4, 2) the rectangle.
    """
    geo = LaneGeometry.from_network(env.network) if geometry is None else geometry
    route = np.asarray(route, np.int64)
    pos = np.asarray(pos, np.float64)
    length = float(env.cfg.drivers.hv.length)
    end = env.network.route_length[route]
    front = geo.points(route, np.clip(pos, 0.0, end))
    back = geo.points(route, np.clip(pos - length, 0.0, end))
    centre = geo.points(route, np.clip(pos - length / 2, 0.0, end))
    chord = front - back
    heading = np.arctan2(chord[:, 1], chord[:, 0])
    u = np.stack([np.cos(heading), np.sin(heading)], 1)[:, None, :]  # (M, 1, 2)
    n = np.stack([-np.sin(heading), np.cos(heading)], 1)[:, None, :]
    along = np.array([1, 1, -1, -1])[None, :, None] * length / 2
    across = np.array([1, -1, -1, 1])[None, :, None] * VEHICLE_WIDTH / 2
    corners = centre[:, None, :] + along * u + across * n  # (M, 4, 2)
    return centre, heading, corners


def _lane_polygon(shape: np.ndarray, width: float) -> np.ndarray:
    """The outline of a lane of `width` around its centre line, float (2n, 2)."""
    d = np.diff(shape, axis=0)
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    t = np.concatenate([d[:1], d[:-1] + d[1:], d[-1:]])  # tangent at each point
    t = t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    n = np.stack([-t[:, 1], t[:, 0]], 1) * width / 2
    return np.concatenate([shape + n, (shape - n)[::-1]])


# ------------------------------------------------------------------ drawing


@dataclass
class _Artists:
    """What changes from frame to frame."""

    geometry: LaneGeometry
    vehicles: PolyCollection
    clock: Text
    waiting: list[Text]


def _host(state: EnvState) -> EnvState:
    """The state as numpy arrays; one roundabout only."""
    s = jax.device_get(state)
    if np.ndim(s.active) != 1:
        raise ValueError(
            f"expected one roundabout, got state.active of shape "
            f"{np.shape(s.active)}; pick one first, e.g. state_at(states, 0)"
        )
    return s


def _draw_network(env: RoundaboutEnv, ax: Axes) -> _Artists:
    """Lanes, legend, empty vehicles and texts on `ax`."""
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    net = env.network
    internal = [lid.startswith(":") for lid in net.lane_ids]
    roads = [_lane_polygon(s, LANE_WIDTH) for s in net.lane_shapes]
    ax.add_collection(
        PolyCollection(roads, facecolors=ROAD_COLOR, edgecolors="none", zorder=1)
    )
    for shape, is_internal in zip(net.lane_shapes, internal, strict=True):
        ax.plot(
            shape[:, 0], shape[:, 1], color="white", lw=0.6, zorder=2,
            ls=":" if is_internal else "--",
        )  # fmt: skip
    pts = np.concatenate(net.lane_shapes)
    lo, hi = pts.min(0) - 2 * LANE_WIDTH, pts.max(0) + 2 * LANE_WIDTH
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_axis_off()

    vehicles = PolyCollection(
        np.zeros((0, 4, 2)), zorder=3, gid=VEHICLES_GID, linewidths=0.5
    )
    ax.add_collection(vehicles)
    waiting = []
    centre = pts.mean(0)
    for leg in range(net.n_legs):
        start = net.lane_shapes[net.entry_lane[leg]][0]
        out = start - centre
        out = out / max(np.linalg.norm(out), 1e-9)
        x, y = start + out * LANE_WIDTH
        waiting.append(ax.text(x, y, "", ha="center", va="center", fontsize=8))
    clock = ax.text(
        0.01, 0.01, "", transform=ax.transAxes, fontsize=8, va="bottom", ha="left"
    )
    ax.legend(
        handles=[
            Patch(facecolor=AV_COLOR, edgecolor=MOVING_EDGE, label="AV"),
            Patch(facecolor=HV_COLOR, edgecolor=MOVING_EDGE, label="human driver"),
            Patch(
                facecolor="none", edgecolor=HALTING_EDGE, lw=1.5,
                label=f"halting (< {HALTING_SPEED:g} m/s)",
            ),
        ],
        loc="upper left", fontsize=7, frameon=False,
        title="+n: waiting to enter", title_fontsize=7,
    )  # fmt: skip
    return _Artists(LaneGeometry.from_network(net), vehicles, clock, waiting)


def _draw_vehicles(env: RoundaboutEnv, art: _Artists, s: EnvState) -> None:
    """Put the vehicles and counts of host state `s` on the artists."""
    active = np.asarray(s.active, bool)
    route, pos = np.asarray(s.route)[active], np.asarray(s.pos)[active]
    _, _, corners = vehicle_boxes(env, route, pos, art.geometry)
    is_av = np.asarray(s.is_av, bool)[active]
    halting = np.asarray(s.speed)[active] < HALTING_SPEED
    art.vehicles.set_verts(list(corners))
    art.vehicles.set_facecolor([AV_COLOR if a else HV_COLOR for a in is_av])
    art.vehicles.set_edgecolor([HALTING_EDGE if h else MOVING_EDGE for h in halting])
    art.vehicles.set_linewidth([1.5 if h else 0.5 for h in halting])
    t = float(s.step) * env.dt
    pending = waiting_to_enter(env, s)
    for text, n in zip(art.waiting, pending, strict=True):
        text.set_text(f"+{n}" if n else "")
    art.clock.set_text(
        f"t = {t:.1f} s   {active.sum()} vehicles ({is_av.sum()} AV), "
        f"{halting.sum()} halting, {pending.sum()} waiting to enter"
    )


def waiting_to_enter(env: RoundaboutEnv, state: EnvState) -> np.ndarray:
    """Vehicles due by the state's time but not yet inserted, int (G,) per leg."""
    s = _host(state)
    t = float(s.step) * env.dt
    due = ~np.asarray(s.inserted, bool) & (np.asarray(s.schedule.depart_s) <= t + 1e-4)
    return np.bincount(np.asarray(s.schedule.origin)[due], minlength=env.n_legs)


def render_state(
    env: RoundaboutEnv,
    state: EnvState,
    ax: Axes | None = None,
    figsize: tuple[float, float] = (6.0, 6.0),
) -> Axes:
    """Draw one roundabout: lanes, vehicles, halting ones, legend and time.

    Args:
        env: the environment whose network `state` drives.
        state: one (unbatched) state; per-vehicle fields (M,).
        ax: axes to draw into; a new pyplot figure if None.
        figsize: size of that new figure, inches.

    Returns:
        The axes. The vehicles are one `PolyCollection` with gid
        `VEHICLES_GID`, one polygon per active slot in slot order.
    """
    s = _host(state)
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    _draw_vehicles(env, _draw_network(env, ax), s)
    return ax


def state_at(states: EnvState, i: int | slice) -> EnvState:
    """Frame `i` (or the frames of a slice) of a stacked trajectory (T, ...)."""
    return jax.tree.map(lambda x: x[i], states)


def n_frames(states: EnvState) -> int:
    """Frames T of a stacked trajectory."""
    shape = np.shape(states.active)
    if len(shape) != 2:
        raise ValueError(
            f"expected a trajectory of one roundabout, state.active of shape "
            f"(T, M); got {shape}"
        )
    return int(shape[0])


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
    art = _draw_network(env, fig.add_subplot())
    path.parent.mkdir(parents=True, exist_ok=True)
    with writer.saving(fig, str(path), dpi):
        for i in range(frames):
            _draw_vehicles(env, art, state_at(host, i))
            writer.grab_frame()
    return path


def plot_vehicle_counts(
    env: RoundaboutEnv, states: EnvState, ax: Axes | None = None
) -> Axes:
    """Vehicles in the network (AVs, human drivers), halting and waiting, over time.

    Args:
        env: the environment the states come from.
        states: stacked states, per-vehicle fields (T, M).
        ax: axes to draw into; a new pyplot figure if None.

    Returns:
        The axes.
    """
    host = jax.device_get(states)
    n_frames(host)  # one roundabout's trajectory, (T, M)
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(7.0, 3.0), layout="constrained")
    active = np.asarray(host.active, bool)  # (T, M)
    is_av = np.asarray(host.is_av, bool) & active
    t = np.asarray(host.step) * env.dt  # (T,)
    halting = active & (np.asarray(host.speed) < HALTING_SPEED)
    due = np.asarray(host.schedule.depart_s) <= t[:, None] + 1e-4  # (T, N)
    waiting = (due & ~np.asarray(host.inserted, bool)).sum(1)
    ax.plot(t, active.sum(1), color="k", label="in the network")
    ax.plot(t, is_av.sum(1), color=AV_COLOR, label="AVs")
    ax.plot(t, (active & ~is_av).sum(1), color="tab:orange", label="human drivers")
    ax.plot(t, halting.sum(1), color=HALTING_EDGE, ls="--", label="halting")
    ax.plot(t, waiting, color="0.5", ls=":", label="waiting to enter")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("vehicles")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncols=2)
    return ax


# ------------------------------------------------------------------ episodes


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
    automatic reset) as `jaxround.rollout.run_episode` does, in one jitted
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
        params = params.replace(penetration=jnp.float32(penetration))
    n_steps = max(every, int(round(seconds / env.dt)))
    states = rollout_states(env, params, jax.random.PRNGKey(seed), n_steps, every=every)
    return animate(env, states, out, fps=fps)
