"""What a study is run with, checked before anything starts."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from jaxround.scenario.config import ScenarioConfig
from jaxround.study.pedals import read_pedal_map

#: The two AV shares of the paper's rides (its Tables 5-7 compare them).
LOW_SHARE = 0.2
HIGH_SHARE = 0.8
#: Most participants driving at once that the server accepts as a setting.
MAX_PARTICIPANTS_LIMIT = 32
#: Longest step of a ride: the issue asks for at least 10 Hz.
MAX_STEP_S = 0.1
#: Shortest wait for the browser's start: the page counts down 2 s between
#: the ride's "ready" and its "start".
MIN_CONNECT_TIMEOUT_S = 3.0
#: Most passes through the roundabout in one ride.
MAX_PASSES = 50
#: What the consent page's estimate adds to the rides' time limits: the
#: pages and the three questions, and each ride's warm-up as a participant
#: waits for it (12-27 s measured with 120 s of warm-up on a 2-core CPU).
FORMS_S = 180.0
WARMUP_WAIT_S = 30.0


@dataclass(frozen=True)
class StudySettings:
    """A study's settings (the `jaxround study serve` options).

    Attributes:
        policy: who drives the AVs: an exported policy (``.npz``/``.json``),
            a scripted controller (``eco``, ``eco+gap:10``) or
            ``uncontrolled`` (`jaxround.apps.drivers`).
        config: the scenario, a YAML path or a built-in name.
        max_participants: rides (SUMO processes) at once; the next
            participant who asks for a ride gets the busy page.
        warmup_s: simulated seconds of background traffic before the ego
            enters, run as fast as SUMO goes (the roundabout is busy then).
        ride_s: longest ride in seconds of driving; it ends earlier when the
            ego has driven its passes.
        passes: times the ego drives its route in a ride (in, round the
            ring, out; then in again from its entry among the same
            traffic). Eight passes take about 70 s with the throttle held
            (8.8 s each), more driving at lower speeds.
        practice_s: longest practice ride (no traffic), seconds.
        practice_passes: passes of the practice ride.
        step_s: SUMO's step in a ride, seconds of real time; the policy acts
            every ``dt_s / step_s`` steps (its trained step).
        blind: label the rides A and B instead of naming their AV shares.
        seed: the background traffic's schedule seed (None: the config's);
            every participant meets the same traffic.
        ego_origin: name of the leg the ego enters from.
        ego_destination: name of the leg it leaves at.
        connect_timeout_s: a ride whose browser does not start it within
            this many seconds after its warm-up is ended (status
            ``not_started``) and reaped. Until then it holds its place: a
            ride asked for and never driven keeps a place for its process's
            start, the warm-up and this long.
        pedal_map: a JSON file of pedal set-ups per gamepad id, used by
            browsers that have not set up that pad themselves
            (`jaxround.study.pedals`).
    """

    policy: str | Path
    config: str = "milan"
    max_participants: int = 4
    warmup_s: float = 120.0
    ride_s: float = 180.0
    passes: int = 8
    practice_s: float = 90.0
    practice_passes: int = 2
    step_s: float = 0.1
    blind: bool = False
    seed: int | None = None
    ego_origin: str = "east"
    ego_destination: str = "south"
    connect_timeout_s: float = 60.0
    pedal_map: Path | None = None

    def validate(self, cfg: ScenarioConfig) -> None:
        """Raise ValueError naming the first setting that cannot work with `cfg`."""
        if not 1 <= self.max_participants <= MAX_PARTICIPANTS_LIMIT:
            raise ValueError(
                f"max participants: {self.max_participants}, expected 1-"
                f"{MAX_PARTICIPANTS_LIMIT}"
            )
        if not 0.0 < self.step_s <= MAX_STEP_S:
            raise ValueError(
                f"step: {self.step_s} s, expected more than 0 and at most "
                f"{MAX_STEP_S} s (10 Hz or faster)"
            )
        ratio = cfg.simulation.dt_s / self.step_s
        if abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                f"step: {self.step_s} s does not divide the policy's step "
                f"{cfg.simulation.dt_s} s (simulation.dt_s of {cfg.name!r})"
            )
        for name in ("ride_s", "practice_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: {getattr(self, name)}, expected > 0")
        for name in ("passes", "practice_passes"):
            if not 1 <= getattr(self, name) <= MAX_PASSES:
                raise ValueError(
                    f"{name}: {getattr(self, name)}, expected 1-{MAX_PASSES}"
                )
        if self.connect_timeout_s < MIN_CONNECT_TIMEOUT_S:
            raise ValueError(
                f"connect timeout: {self.connect_timeout_s} s, expected at least "
                f"{MIN_CONNECT_TIMEOUT_S} s (the page counts down before it starts)"
            )
        if self.warmup_s < 0:
            raise ValueError(f"warm-up: {self.warmup_s} s, expected >= 0")
        if self.warmup_s + self.ride_s > cfg.demand.duration_s:
            raise ValueError(
                f"warm-up {self.warmup_s} s + ride {self.ride_s} s is longer than "
                f"the demand of {cfg.name!r} ({cfg.demand.duration_s} s)"
            )
        if self.seed is not None and self.seed < 0:
            raise ValueError(f"seed: {self.seed}, expected >= 0")
        if self.pedal_map is not None:
            read_pedal_map(self.pedal_map)
        origin = leg_index(cfg, self.ego_origin)
        if origin == leg_index(cfg, self.ego_destination):
            raise ValueError(
                f"the ego enters and leaves at leg {self.ego_origin!r}: choose "
                "another exit"
            )

    def estimated_minutes(self) -> int:
        """What the consent page promises: the study at most takes about
        this long (the rides' time limits, their warm-ups, the forms)."""
        rides = self.practice_s + 2 * (self.ride_s + WARMUP_WAIT_S)
        return math.ceil((rides + FORMS_S) / 60.0)

    def schedule_seed(self, cfg: ScenarioConfig) -> int:
        return cfg.simulation.seed if self.seed is None else self.seed

    def replace(self, **changes: object) -> StudySettings:
        return dataclasses.replace(self, **changes)


def leg_index(cfg: ScenarioConfig, name: str) -> int:
    """The index of the leg called `name`; ValueError listing the names."""
    names = [leg.name for leg in cfg.network.legs]
    if name not in names:
        raise ValueError(f"leg {name!r}: {cfg.name!r} has legs {names}")
    return names.index(name)


def share_label(share: float) -> str:
    """0.2 -> '20%'."""
    return f"{round(share * 100)}%"
