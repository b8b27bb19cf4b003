"""The AVs' driver named on the command line, in both simulators.

A driver spec is one of

- ``uncontrolled`` (or None): the AVs drive their vType, no commands;
- a scripted controller, ``accel:A``, ``cruise:V``, ``eco[:B]``,
  ``timed[:H]`` (`jaxround.envs.scripted`), with a lane rule after ``+``
  (``inner``, ``outer``, ``gap:X``) or a lane rule alone;
- an exported policy: a ``.npz``/``.json`` file, its stem or a training folder
  (`agents.common.export`).

`jax_driver` gives the JAX `jaxround.envs.rollout.Policy`; `sumo_driver` the
controller factory that drives SUMO's AVs the same way
(`sumo_export.runner.ControllerFactory`). Both are checked before any work
starts; a bad spec raises ValueError naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp

from jaxround.core.params import EnvParams
from jaxround.core.state import EnvState
from jaxround.envs.lane_view import observation_by_name
from jaxround.envs.rollout import Policy, uncontrolled_policy
from jaxround.envs.roundabout import RoundaboutEnv
from jaxround.envs.scripted import controller_from_spec, is_scripted_spec
from jaxround.scenario.config import ScenarioConfig, config_from_dict

UNCONTROLLED = "uncontrolled"


@dataclass(frozen=True)
class DriverSpec:
    """A checked driver spec.

    Attributes:
        spec: as given (``uncontrolled``, a scripted spec or a policy path).
        kind: ``"uncontrolled"``, ``"scripted"`` or ``"policy"``.
        observer: the observer the driver reads (None when uncontrolled).
        action: what its action means (`jaxround.scenario.config.ACTIONS`).
    """

    spec: str
    kind: str
    observer: str | None
    action: str = "accel"


def parse_driver(spec: str | None) -> DriverSpec:
    """Check a driver spec before anything runs.

    Raises:
        ValueError: neither a scripted controller nor a readable policy; the
            message names the spec.
    """
    if spec is None or spec == UNCONTROLLED:
        return DriverSpec(UNCONTROLLED, UNCONTROLLED, None)
    if is_scripted_spec(spec):
        controller = controller_from_spec(spec)  # raises on a bad value
        return DriverSpec(spec, "scripted", controller.observer)
    from agents.common.export import load_policy

    try:
        _, layout = load_policy(spec)
    except FileNotFoundError as err:
        raise ValueError(
            f"driver {spec!r}: no exported policy there ({err}); a driver is "
            "'uncontrolled', accel:A, cruise:V, eco[:B], timed[:H] (+inner, "
            "+outer, +gap:X, or one of those alone) or a policy "
            "file (.npz/.json, its stem or a training folder)"
        ) from None
    return DriverSpec(spec, "policy", layout.observer, layout.action)


#: AV vType numbers a command line may set (`with_av_numbers`).
AV_NUMBERS = ("tau", "impatience", "accel", "jm_timegap_minor")


def parse_av_numbers(text: str) -> dict[str, float]:
    """``"tau=0.5,impatience=1"`` -> ``{"tau": 0.5, "impatience": 1.0}``.

    Raises:
        ValueError: a name not in `AV_NUMBERS` or a value that is no number.
    """
    numbers: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        if not sep or name not in AV_NUMBERS:
            raise ValueError(
                f"AV numbers {text!r}: {item!r} is not NAME=VALUE with NAME one "
                f"of {', '.join(AV_NUMBERS)}"
            )
        try:
            numbers[name] = float(value)
        except ValueError:
            message = f"AV numbers {text!r}: {value!r} is not a number"
            raise ValueError(message) from None
    return numbers


def with_av_numbers(cfg: ScenarioConfig, numbers: dict[str, float]) -> ScenarioConfig:
    """`cfg` with these numbers in the AVs' vType (both simulators read it),
    validated; e.g. ``{"tau": 0.5, "impatience": 1.0}``."""
    if not numbers:
        return cfg
    data = cfg.to_dict()
    data["drivers"]["av"].update(numbers)
    return config_from_dict(data)


def config_for(cfg: ScenarioConfig, driver: DriverSpec) -> ScenarioConfig:
    """`cfg` with the observer and action a driver reads and gives."""
    observer = driver.observer or cfg.agent.observer
    if cfg.agent.observer == observer and cfg.agent.action == driver.action:
        return cfg
    d = cfg.to_dict()
    d["agent"]["observer"] = observer
    d["agent"]["action"] = driver.action
    return config_from_dict(d)


def jax_driver(env: RoundaboutEnv, params: EnvParams, driver: DriverSpec) -> Policy:
    """The JAX policy ``act(obs, state, key) -> action (M, 2)`` of a driver.

    For a policy file, `env` must use the policy's observer (`config_for`).
    """
    if driver.kind == UNCONTROLLED:
        return uncontrolled_policy(env)
    if driver.kind == "scripted":
        controller = controller_from_spec(driver.spec, dt_s=env.dt)

        lanes = None if env.lane_changer is None else env.lane_changer.arrays

        def scripted(obs: jax.Array, state: EnvState, key: jax.Array) -> jax.Array:
            del obs, key
            rows = observation_by_name(
                controller.observer, env.net, lanes, state, params,
                env.route_destination,
            )  # fmt: skip
            return controller.action(rows)

        return scripted
    from agents.common.evaluation import switched_policy
    from agents.common.export import load_policy

    arrays, layout = load_policy(driver.spec)
    weights = {k: jnp.asarray(v) for k, v in arrays.items()}
    return switched_policy(weights, layout, jnp.bool_(True))


def sumo_driver(driver: DriverSpec) -> Any:
    """The `sumo_export.runner.ControllerFactory` of a driver (None: uncontrolled)."""
    if driver.kind == UNCONTROLLED:
        return None
    if driver.kind == "scripted":
        from sumo_export.scripted import ScriptedControllerFactory

        return ScriptedControllerFactory(driver.spec)
    from sumo_export.controller import PolicyControllerFactory

    return PolicyControllerFactory(driver.spec)
