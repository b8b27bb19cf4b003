"""Vehicle slots sized by the traffic, and runs redone when they were too few.

The JAX environment keeps every vehicle on the road in one of M slots, and
each step costs about M squared. What the road can hold
(`jaxround.core.capacity.road_capacity`, 76 for Milan) is what no run can
outgrow, but a scenario's demand fills a small part of it: Milan never holds
more than 23 vehicles at its default demand, 28 at ten times that. So the
default M is measured from the traffic:

- `traffic_slots` runs the scenario's own demand in JAX (``SIZING_SEEDS``
  schedules, half of them human drivers only and half AVs only, over the
  first ``SIZING_SECONDS`` of the demand) with ``SIZING_PROBE`` slots, or
  the road's M where those overflowed, takes the most vehicles any step
  held, and adds a margin (`slots_for_peak`). The result
  is cached per scenario fingerprint (network, demand, drivers, dt) next to
  the network cache, so each scenario is measured once per machine.
- `redo_on_overflow` runs a computation at M and, if an insertion ever
  waited for a free slot (``EnvState.stats.overflow``), runs it again with
  twice the slots (at most the road's), saying so on stderr. A run with
  overflow is never the one reported: the road's M cannot overflow.

`resolve_slots` says which M an environment gets: a number given, else the
config's ``simulation.max_vehicles``, else the traffic's; ``"road"`` asks for
what the road holds.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxround.core.capacity import road_capacity
from jaxround.core.network import CompiledNetwork
from jaxround.scenario.config import ScenarioConfig
from jaxround.scenario.schedule import make_schedule


class MeasuredEnv(Protocol):
    """What the measurement steps: the environment (`RoundaboutEnv`), given
    by its caller so that this module need not import it."""

    max_vehicles: int
    episode_steps: int
    default_params: Any

    def schedule_from_numpy(self, schedule: Any) -> Any: ...

    def reset_to_schedule(self, schedule: Any, params: Any) -> tuple: ...

    def step_env(self, key: Any, state: Any, action: Any, params: Any) -> tuple: ...


#: Builds the measuring environment: (slots M, episode seconds) -> environment.
EnvFactory = Callable[[int, float], MeasuredEnv]

#: Schedules of the measurement (half human drivers only, half AVs only).
SIZING_SEEDS = 8
#: Simulated seconds of each (at most the demand's duration).
SIZING_SECONDS = 900.0
#: Seeds of the measured schedules: far from the seeds runs use (0, 1, ...).
SIZING_SEED = 900_000
#: Slots of the measuring runs (the road's where these overflow): more than
#: Milan holds at ten times its demand, and cheaper to compile than the road's.
SIZING_PROBE = 48
#: Slots per vehicle of the measured peak ...
MARGIN = 1.25
#: ... rounded up to a multiple of this.
ROUND_TO = 8
#: Bumped when the step changes in a way that could change the peak.
SIZING_VERSION = 1
#: The value of ``max_vehicles`` that asks for what the road holds.
ROAD = "road"

T = TypeVar("T")


@dataclass(frozen=True)
class SlotSizing:
    """`traffic_slots`: max_vehicles the slots M; peak the most vehicles a
    step of the measurement held; road what the road holds; seeds, seconds
    the measurement's size."""

    max_vehicles: int
    peak: int
    road: int
    seeds: int
    seconds: float


def slots_for_peak(peak: int, road: int) -> int:
    """`MARGIN` times `peak`, rounded up to a multiple of `ROUND_TO`, at
    least `ROUND_TO` and at most `road`."""
    wanted = max(ROUND_TO, math.ceil(peak * MARGIN / ROUND_TO) * ROUND_TO)
    return int(min(wanted, road))


def _cache_file(cfg: ScenarioConfig) -> Path:
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return cache / "jaxround" / "slots" / f"{cfg.name}-{cfg.fingerprint()}.json"


def _read_cache(path: Path) -> SlotSizing | None:
    try:
        data = json.loads(path.read_text())
        if data.pop("version") != SIZING_VERSION:
            return None
        return SlotSizing(**data)
    except (OSError, ValueError, KeyError, TypeError):
        return None  # absent or unreadable: measure again


def _write_cache(path: Path, sizing: SlotSizing) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(
        "w", dir=path.parent, suffix=".tmp", delete=False
    ) as tmp:
        json.dump({"version": SIZING_VERSION, **asdict(sizing)}, tmp)
    os.replace(tmp.name, path)  # parallel processes never see half a file


def peak_occupancy(env: MeasuredEnv, schedules: list, steps: int) -> tuple[int, int]:
    """The most vehicles any of `steps` steps held, over the schedules (numpy
    `Schedule`s) run side by side in one vmapped scan, AVs uncontrolled, and
    the runs' slot overflow (vehicle-steps)."""
    params = env.default_params
    batch = jax.tree.map(
        lambda *xs: np.stack(xs), *[env.schedule_from_numpy(s) for s in schedules]
    )
    action = jnp.full((env.max_vehicles, 2), jnp.nan, jnp.float32)
    key = jax.random.PRNGKey(0)  # step_env does not use it

    def one(schedule: object) -> tuple[jax.Array, jax.Array]:
        _, state = env.reset_to_schedule(schedule, params)

        def body(carry: tuple, _: None) -> tuple:
            state, most = carry
            _, state, _, _, _ = env.step_env(key, state, action, params)
            return (state, jnp.maximum(most, jnp.sum(state.active))), None

        (state, most), _ = jax.lax.scan(body, (state, jnp.int32(0)), None, length=steps)
        return most, state.stats.overflow

    most, overflow = jax.jit(jax.vmap(one))(batch)
    return int(np.max(most)), int(np.sum(overflow))


def traffic_slots(
    cfg: ScenarioConfig, network: CompiledNetwork, build_env: EnvFactory
) -> SlotSizing:
    """The slots the scenario's demand needs (see the module docstring);
    measured once per scenario fingerprint, then read from the cache.

    Args:
        build_env: (slots M, episode seconds) -> the scenario's environment.
    """
    path = _cache_file(cfg)
    cached = _read_cache(path)
    if cached is not None:
        return cached
    road = road_capacity(network, cfg)
    seconds = min(SIZING_SECONDS, cfg.demand.duration_s)
    schedules = [
        make_schedule(cfg, seed=SIZING_SEED + i, penetration=float(i % 2))
        for i in range(SIZING_SEEDS)
    ]
    for slots in sorted({min(SIZING_PROBE, road), road}):
        env = build_env(slots, seconds)
        peak, overflow = peak_occupancy(env, schedules, env.episode_steps)
        if not overflow:
            break
    sizing = SlotSizing(slots_for_peak(peak, road), peak, road, SIZING_SEEDS, seconds)
    _write_cache(path, sizing)
    return sizing


def resolve_slots(
    max_vehicles: int | str | None,
    cfg: ScenarioConfig,
    network: CompiledNetwork,
    build_env: EnvFactory,
) -> int:
    """The slots M an environment gets: `max_vehicles` if given, else the
    config's ``simulation.max_vehicles``, else `traffic_slots` (measured in
    environments of `build_env`); ``"road"`` (either place) gives what the
    road holds.

    Raises:
        ValueError: a `max_vehicles` that is not a positive integer or "road".
    """
    if max_vehicles is None:
        max_vehicles = cfg.simulation.max_vehicles
    if max_vehicles is None:
        return traffic_slots(cfg, network, build_env).max_vehicles
    if max_vehicles == ROAD:
        return road_capacity(network, cfg)
    if isinstance(max_vehicles, bool | str) or int(max_vehicles) != max_vehicles:
        raise ValueError(
            f"max_vehicles: {max_vehicles!r}, expected a positive integer or {ROAD!r}"
        )
    if max_vehicles < 1:
        raise ValueError(f"max_vehicles: {max_vehicles}, expected >= 1")
    return int(max_vehicles)


def redo_on_overflow(
    run: Callable[[int], T],
    overflow: Callable[[T], int],
    *,
    max_vehicles: int,
    road: int,
    what: str,
    note: Callable[[str], None] | None = None,
) -> tuple[T, list[int]]:
    """`run(M)` from `max_vehicles` slots, redone with twice the slots (at
    most `road`) while `overflow(result)` says an insertion waited for a
    free slot.

    Args:
        run: M -> result.
        overflow: result -> vehicle-steps of slot overflow.
        road: what the road holds (cannot overflow).
        what: the runs, for the note.
        note: where the note goes (default: a line on stderr).

    Returns:
        (the result without overflow, the slot counts tried in order; the
        last is the result's).
    """
    say = note or (lambda text: print(text, file=sys.stderr))
    tried = [int(max_vehicles)]
    while True:
        result = run(tried[-1])
        lost = int(overflow(result))
        if not lost or tried[-1] >= road:
            return result, tried
        more = min(road, 2 * tried[-1])
        say(
            f"note: {what}: {lost} vehicle-steps of slot overflow with "
            f"max_vehicles = {tried[-1]}; redone with {more} slots (the "
            "overflowing run is not reported)"
        )
        tried.append(more)
