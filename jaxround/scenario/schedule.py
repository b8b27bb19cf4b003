"""Departure schedules: exactly N vehicles, drawn once and read by both simulators.

A schedule is a set of plain NumPy arrays (saved as ``.npz`` without pickles).
Everything SUMO would otherwise draw by itself per vehicle (the desired-speed
factor) is drawn here, so the JAX environment and SUMO see the same vehicles.

The draw depends on the seed only; the penetration only chooses which vehicles
are AVs, through a fixed random rank per vehicle. So the schedules of one seed
at 0%, 10%, ... 100% have the same departures and routes, and the AVs at 10%
are a subset of the AVs at 20%.
"""

from __future__ import annotations

import dataclasses
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxround.scenario.config import DemandConfig, ScenarioConfig

SCHEDULE_FIELDS = ("depart_s", "origin", "destination", "speed_factor", "av_rank")


@dataclass(frozen=True)
class Schedule:
    """The vehicles of one run, sorted by departure. All arrays have shape (N,).

    Attributes:
        depart_s: float64 (N,) departure times, multiples of the step length.
        origin: int32 (N,) leg index the vehicle enters from.
        destination: int32 (N,) leg index the vehicle leaves at.
        speed_factor: float64 (N,) desired-speed factor (SUMO's speedFactor).
        av_rank: int32 (N,) a permutation of 0..N-1; the vehicle is an AV at
            penetration p when its rank is below round(p * N).
        penetration: share of AVs this schedule was made for.
    """

    depart_s: np.ndarray
    origin: np.ndarray
    destination: np.ndarray
    speed_factor: np.ndarray
    av_rank: np.ndarray
    penetration: float

    @property
    def n_vehicles(self) -> int:
        return int(self.depart_s.shape[0])

    @property
    def n_av(self) -> int:
        return n_av_at(self.penetration, self.n_vehicles)

    @property
    def is_av(self) -> np.ndarray:
        """bool (N,): which vehicles are AVs at this schedule's penetration."""
        return self.av_rank < self.n_av

    def class_speed_factors(
        self, hv_speed_dev: float, av_speed_dev: float
    ) -> np.ndarray:
        """float64 (N,): the speedFactor each vehicle drives with in its class.

        `speed_factor` is drawn with the human drivers' deviation; an AV scales
        its deviation from 1 to its own class's (speedDev 0: exactly 1), so a
        vehicle keeps its rank whichever class it has at a penetration.
        """
        scale = av_speed_dev / hv_speed_dev if hv_speed_dev > 0 else 0.0
        av = np.round(1.0 + (self.speed_factor - 1.0) * scale, 4)
        return np.where(self.is_av, av, self.speed_factor)

    def with_penetration(self, penetration: float) -> Schedule:
        """The same vehicles with another share of AVs."""
        if not 0.0 <= penetration <= 1.0:
            raise ValueError(f"penetration: {penetration}, expected a share in [0, 1]")
        return dataclasses.replace(self, penetration=float(penetration))

    def save(self, path: str | Path) -> None:
        """Write the arrays to an ``.npz`` file (plain arrays, no pickles)."""
        arrays = {name: getattr(self, name) for name in SCHEDULE_FIELDS}
        np.savez(Path(path), penetration=np.float64(self.penetration), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Schedule:
        """Read a schedule written by `save`; a damaged file raises ValueError."""
        try:
            with np.load(Path(path), allow_pickle=False) as data:
                missing = [
                    k for k in (*SCHEDULE_FIELDS, "penetration") if k not in data
                ]
                if missing:
                    raise ValueError(f"{path}: not a schedule, missing {missing}")
                fields = {k: np.asarray(data[k]) for k in SCHEDULE_FIELDS}
                penetration = float(data["penetration"])
        except (OSError, zipfile.BadZipFile, EOFError) as err:
            raise ValueError(f"{path}: cannot read schedule ({err})") from None
        n = fields["depart_s"].shape[0]
        if any(a.shape != (n,) for a in fields.values()):
            raise ValueError(f"{path}: schedule arrays differ in length")
        return cls(penetration=penetration, **fields)


def n_av_at(penetration: float, n_vehicles: int) -> int:
    """Exact number of AVs: round(p * N), halves rounded up (154 of 1540 at 10%)."""
    return int(np.floor(penetration * n_vehicles + 0.5 + 1e-9))


def make_schedule(
    cfg: ScenarioConfig, seed: int | None = None, penetration: float | None = None
) -> Schedule:
    """Draw the departure schedule of a scenario.

    Args:
        cfg: the scenario; its demand section sets N, the horizon and the OD split.
        seed: defaults to ``cfg.simulation.seed``.
        penetration: share of AVs, defaults to ``cfg.simulation.penetration``.

    Returns:
        A `Schedule` of exactly ``cfg.demand.n_vehicles`` vehicles.
    """
    seed = cfg.simulation.seed if seed is None else int(seed)
    penetration = cfg.simulation.penetration if penetration is None else penetration
    if seed < 0:
        raise ValueError(f"seed: {seed}, expected >= 0")
    if not 0.0 <= penetration <= 1.0:
        raise ValueError(f"penetration: {penetration}, expected a share in [0, 1]")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    demand = cfg.demand
    n = demand.n_vehicles
    depart = departure_times(rng, n, demand.duration_s, cfg.simulation.dt_s)
    origin, destination = draw_routes(rng, demand)
    speed_factor = draw_speed_factors(rng, n, cfg.drivers.hv.speed_dev)
    av_rank = rng.permutation(n).astype(np.int32)
    return Schedule(
        depart_s=depart,
        origin=origin,
        destination=destination,
        speed_factor=speed_factor,
        av_rank=av_rank,
        penetration=float(penetration),
    )


def departure_times(
    rng: np.random.Generator, n: int, duration_s: float, dt_s: float
) -> np.ndarray:
    """N Poisson arrivals in [0, duration) conditioned on their count, on the step grid.

    Returns:
        float64 (n,) sorted times, each a multiple of `dt_s`.
    """
    t = np.sort(rng.uniform(0.0, duration_s, size=n))
    steps = np.floor(t / dt_s)
    last = max(np.ceil(duration_s / dt_s) - 1, 0)
    return np.minimum(steps, last) * dt_s


def draw_routes(
    rng: np.random.Generator, demand: DemandConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Origins by `origin_share`, then destinations by the origin's `od` row.

    Returns:
        (origin, destination), int32 arrays of shape (n_vehicles,).
    """
    n_legs = len(demand.origin_share)
    share = np.asarray(demand.origin_share, dtype=np.float64)
    origin = rng.choice(n_legs, size=demand.n_vehicles, p=share / share.sum())
    od = np.asarray(demand.od, dtype=np.float64)
    cum = np.cumsum(od / od.sum(axis=1, keepdims=True), axis=1)
    u = rng.uniform(size=demand.n_vehicles)
    destination = np.argmax(u[:, None] < cum[origin], axis=1)
    return origin.astype(np.int32), destination.astype(np.int32)


def draw_speed_factors(
    rng: np.random.Generator, n: int, speed_dev: float
) -> np.ndarray:
    """SUMO's default speed-factor distribution normc(1, dev, 0.2, 2), by resampling.

    Returns:
        float64 (n,) factors within [0.2, 2], rounded to 4 decimals so that the
        route file carries them exactly.
    """
    out = 1.0 + speed_dev * rng.standard_normal(n)
    for _ in range(100):
        bad = (out < 0.2) | (out > 2.0)
        if not bad.any():
            break
        out[bad] = 1.0 + speed_dev * rng.standard_normal(int(bad.sum()))
    return np.round(np.clip(out, 0.2, 2.0), 4)
