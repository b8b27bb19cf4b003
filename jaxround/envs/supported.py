"""What of a scenario the JAX environment runs, checked before it is built.

SUMO runs every valid scenario; the JAX environment (`jaxround.envs.roundabout`)
runs those with one lane on every road, whose two driver classes share the
vType numbers it keeps once (`jaxround.scenario.config.SHARED_DRIVER_FIELDS`).
A config outside that gets a `ConfigError` naming its keys, before netconvert
or SUMO runs.
"""

from __future__ import annotations

from jaxround.scenario.config import (
    SHARED_DRIVER_FIELDS,
    ConfigError,
    ScenarioConfig,
)


def check_single_lane(cfg: ScenarioConfig) -> None:
    """The JAX environment has one lane on every road; a config with a
    two-lane ring, entry or exit gets a clear error naming those keys."""
    keys = cfg.network.multi_lane_keys()
    if keys:
        raise ConfigError(
            f"{', '.join(keys)}: two-lane roundabouts run in SUMO only for now "
            "(`jaxround sumo`, `sumo_export.runner`); the JAX environment, and "
            "so parity, training and evaluation in JAX, has one lane per road"
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
