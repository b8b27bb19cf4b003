"""What of a scenario the JAX environment runs, checked before it is built.

SUMO runs every valid scenario; the JAX environment (`jaxround.envs.roundabout`)
runs those with one-lane exits (rings and entries of one or two lanes),
whose two driver classes share the vType numbers it keeps once
(`jaxround.scenario.config.SHARED_DRIVER_FIELDS`); training, evaluation,
the search of constant AV settings and the main job run on them too.
Headroom still needs one lane on every road (`check_single_lane`).
A config outside that gets a `ConfigError` naming its keys, before netconvert
or SUMO runs.
"""

from __future__ import annotations

from jaxround.scenario.config import (
    SHARED_DRIVER_FIELDS,
    ConfigError,
    ScenarioConfig,
)


def check_single_lane(cfg: ScenarioConfig, what: str = "this command") -> None:
    """What still needs one lane on every road (headroom: its vType sweeps
    and scripted strategies are one-lane ones) refuses a config with a
    two-lane ring, entry or exit, naming those keys and `what` it was asked
    for."""
    keys = cfg.network.multi_lane_keys()
    if keys:
        raise ConfigError(
            f"{', '.join(keys)}: {what} needs one lane on every road for now. "
            "On two-lane roads `jaxround run --config ...` (the main job), "
            "`jaxround train --config ppo_two_lane`, `jaxround evaluate`, "
            "`jaxround search` and `jaxround parity --config "
            "... [--controller ...]` run (human drivers, uncontrolled AVs, scripted "
            "lane rules and policies, in both simulators)"
        )


def check_jax_lanes(cfg: ScenarioConfig) -> None:
    """The JAX environment drives one-lane exits only: netconvert gives the
    inner ring lane's exit an internal junction (a second yield point inside
    the junction) that the step does not have; a config with a two-lane exit
    gets a clear error naming those keys."""
    keys = [
        f"network.legs[{i}].exit_lanes: 2"
        for i, leg in enumerate(cfg.network.legs)
        if leg.exit_lanes != 1
    ]
    if keys:
        raise ConfigError(
            f"{', '.join(keys)}: two-lane exits run in SUMO only for now "
            "(`jaxround sumo`, `sumo_export.runner`); the JAX environment "
            "drives two-lane rings and entries with one-lane exits"
        )


def check_driver_classes(cfg: ScenarioConfig) -> None:
    """The JAX environment drives both classes with the IDM and shares some of
    their numbers; a config that differs there gets a clear error."""
    hv, av = cfg.drivers.hv, cfg.drivers.av
    for name in ("car_follow_model", *SHARED_DRIVER_FIELDS):
        if getattr(hv, name) != getattr(av, name):
            raise ConfigError(
                f"drivers.av.{name}: {getattr(av, name)!r} differs from "
                f"drivers.hv.{name} {getattr(hv, name)!r}; the JAX environment "
                "drives both classes as an IDM with these numbers shared (AVs may "
                "differ in accel, tau, jm_timegap_minor, impatience, speed_dev)"
            )
