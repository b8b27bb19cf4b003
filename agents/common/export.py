"""The trained policy as plain arrays: ``policy.npz`` plus ``policy.json``.

    export_policy(runner.params, layout, "out/policy")   # writes both files
    act = load_policy_numpy("out/policy.npz")             # NumPy only
    accel, change = act(obs, mask)                         # obs (M, D), mask (M,)

The ``.npz`` holds the actor's weights (no pickles); the ``.json`` its layout
(layer widths, activation, centralised input, observer and its size, the
bounds of the acceleration command, the lane choices, the scenario it was
trained on). The exported policy acts deterministically: the mean command
clipped to the bounds, and the likeliest lane choice. `policy_action` computes it with
NumPy or JAX from the same code as the trained network (`agents.common.networks`).
There is no observation normalisation: the observer scales its own features.
"""

from __future__ import annotations

import dataclasses
import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from agents.common import networks

if TYPE_CHECKING:
    from agents.common.batch import BatchTrainer
    from jaxround.scenario.config import ScenarioConfig

#: Version of the file layout; a reader refuses other versions.
FORMAT = "jaxround-policy/1"
#: File stem used inside a training folder.
POLICY_STEM = "policy"


@dataclass(frozen=True)
class PolicyLayout:
    """What a reader needs besides the weights to run the policy."""

    observer: str  # name of the observer the policy reads (jaxround.envs.observe)
    obs_size: int  # numbers per observation row, D
    hidden: tuple[int, ...]  # MLP layer widths
    activation: str  # "tanh" or "relu"
    centralised: bool  # rows carry the mean of the other vehicles' rows
    accel_bounds: tuple[float, float]  # lowest and highest command, m/s^2
    action: str = "accel"  # what the action means (the scenario's agent.action)
    scenario: str = ""  # scenario the policy was trained on (name or path)
    scenario_fingerprint: str = ""  # its roads and drivers (ScenarioConfig method)
    # lane choices C: 2 (keep, left), 3 on two-lane roads (none, left, right)
    lane_choices: int = networks.N_LANE_CHOICES

    def array_shapes(self) -> dict[str, tuple[int, ...]]:
        """Name -> shape of every array of the ``.npz``."""
        shapes: dict[str, tuple[int, ...]] = {}
        width = networks.n_inputs(self.obs_size, self.centralised)
        for i, h in enumerate(self.hidden):
            shapes[f"actor_{i}/kernel"] = (width, h)
            shapes[f"actor_{i}/bias"] = (h,)
            width = h
        shapes["accel_mean/kernel"] = (width, 1)
        shapes["accel_mean/bias"] = (1,)
        shapes["lane_logits/kernel"] = (width, self.lane_choices)
        shapes["lane_logits/bias"] = (self.lane_choices,)
        shapes["log_std"] = ()
        return shapes


def policy_layout(trainer: BatchTrainer) -> PolicyLayout:
    """The exported layout of a trainer's network."""
    cfg, scenario = trainer.config, trainer.scenario
    return PolicyLayout(
        observer=scenario.agent.observer,
        obs_size=trainer.obs_size,
        hidden=tuple(cfg.hidden),
        activation=cfg.activation,
        centralised=cfg.centralised,
        accel_bounds=action_bounds(scenario),
        action=scenario.agent.action,
        scenario=cfg.scenario,
        scenario_fingerprint=scenario.roads_and_drivers_fingerprint(),
        lane_choices=trainer.network.lane_choices,
    )


def action_bounds(scenario: ScenarioConfig) -> tuple[float, float]:
    """The exported policy's action bounds: the AV's [-decel, accel] for a
    speed command, `jaxround.envs.assertiveness.RAW_BOUND` for assertiveness."""
    if scenario.agent.action == "assertiveness":
        from jaxround.envs.assertiveness import RAW_BOUND

        return (-RAW_BOUND, RAW_BOUND)
    return (-scenario.drivers.av.decel, scenario.drivers.av.accel)


def policy_paths(path: str | Path) -> tuple[Path, Path]:
    """(npz, json) paths of a policy given as ``.npz``, ``.json``, stem or folder."""
    path = Path(path)
    if path.is_dir():
        path = path / POLICY_STEM
    if path.suffix in (".npz", ".json"):
        path = path.with_suffix("")
    return path.with_name(path.name + ".npz"), path.with_name(path.name + ".json")


def export_policy(
    params: Any, layout: PolicyLayout, path: str | Path
) -> tuple[Path, Path]:
    """Write the actor's weights and layout.

    Args:
        params: the `ActorCritic` variables (``{"params": {...}}``), unbatched.
        layout: the network's layout.
        path: a stem, ``.npz`` or ``.json`` path, or a folder (``policy.*``).

    Returns:
        The (npz, json) paths written.
    """
    tree = params["params"]
    arrays: dict[str, np.ndarray] = {"log_std": np.asarray(tree["log_std"])}
    for name in layout.array_shapes():
        if "/" in name:
            layer, leaf = name.split("/")
            arrays[name] = np.asarray(tree[layer][leaf])
    _check_shapes(arrays, layout, "params")
    check_finite(arrays, "params")
    npz, js = policy_paths(path)
    npz.parent.mkdir(parents=True, exist_ok=True)
    np.savez(npz, **{k: v.astype(np.float32) for k, v in arrays.items()})
    meta = {"format": FORMAT, **dataclasses.asdict(layout)}
    meta["arrays"] = {k: list(v) for k, v in layout.array_shapes().items()}
    js.write_text(json.dumps(meta, indent=2) + "\n")
    return npz, js


def load_policy(path: str | Path) -> tuple[dict[str, np.ndarray], PolicyLayout]:
    """Read an exported policy: (float32 arrays by name, layout).

    Raises:
        FileNotFoundError: a file is missing.
        ValueError: the files are damaged or do not match each other.
    """
    npz, js = policy_paths(path)
    for f in (npz, js):
        if not f.is_file():
            raise FileNotFoundError(f"policy file {f} does not exist")
    try:
        meta = json.loads(js.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{js}: not valid JSON ({err})") from None
    if meta.get("format") != FORMAT:
        raise ValueError(f"{js}: format {meta.get('format')!r}, expected {FORMAT!r}")
    names = [f.name for f in dataclasses.fields(PolicyLayout)]
    try:
        layout = PolicyLayout(
            observer=str(meta["observer"]),
            obs_size=int(meta["obs_size"]),
            hidden=tuple(int(h) for h in meta["hidden"]),
            activation=str(meta["activation"]),
            centralised=bool(meta["centralised"]),
            accel_bounds=(
                float(meta["accel_bounds"][0]),
                float(meta["accel_bounds"][1]),
            ),
            action=str(meta.get("action", "accel")),
            scenario=str(meta.get("scenario", "")),
            scenario_fingerprint=str(meta.get("scenario_fingerprint", "")),
            lane_choices=int(meta.get("lane_choices", networks.N_LANE_CHOICES)),
        )
    except (KeyError, TypeError, IndexError, ValueError) as err:
        raise ValueError(f"{js}: bad layout ({err!r}); fields: {names}") from None
    choices = (networks.N_LANE_CHOICES, networks.N_LANE_CHOICES_TWO_LANE)
    if layout.lane_choices not in choices:
        raise ValueError(
            f"{js}: lane_choices {layout.lane_choices}, expected one of {choices}"
        )
    try:
        with np.load(npz, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k], np.float32) for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise ValueError(f"{npz}: damaged or not a policy file ({err})") from None
    _check_shapes(arrays, layout, str(npz))
    check_finite(arrays, str(npz))
    return arrays, layout


def check_scenario(layout: PolicyLayout, cfg: Any) -> None:
    """Refuse a policy trained on other roads or drivers than `cfg`'s.

    Args:
        layout: the policy's layout.
        cfg: a `jaxround.scenario.config.ScenarioConfig`.

    Raises:
        ValueError: naming both scenarios.
    """
    mine = cfg.roads_and_drivers_fingerprint()
    if layout.scenario_fingerprint and layout.scenario_fingerprint != mine:
        raise ValueError(
            f"the policy was trained on scenario {layout.scenario!r} (roads and "
            f"drivers {layout.scenario_fingerprint}); {cfg.name!r} has other roads "
            f"or drivers ({mine})"
        )


def policy_action(
    arrays: dict[str, Any],
    layout: PolicyLayout,
    obs: Any,
    mask: Any,
    xp: ModuleType = np,
) -> tuple[Any, Any]:
    """The deterministic action of every slot, in NumPy or JAX.

    Args:
        arrays: the weights (`load_policy`), NumPy or JAX arrays.
        layout: the layout.
        obs: float (..., M, D) observation rows.
        mask: bool (..., M) slots that hold a vehicle.
        xp: `numpy` or `jax.numpy`.

    Returns:
        (accel float (..., M) in `accel_bounds`, change int (..., M): the
        lane choice, `agents.common.networks.lane_column`).
    """
    act = networks.activation(layout.activation, xp)
    x = networks.policy_inputs(
        xp.asarray(obs, xp.float32), xp.asarray(mask, bool), layout.centralised, xp
    )
    for i in range(len(layout.hidden)):
        x = act(x @ arrays[f"actor_{i}/kernel"] + arrays[f"actor_{i}/bias"])
    mean = (x @ arrays["accel_mean/kernel"] + arrays["accel_mean/bias"])[..., 0]
    logits = x @ arrays["lane_logits/kernel"] + arrays["lane_logits/bias"]
    return networks.deterministic_action(mean, logits, layout.accel_bounds, xp)


def load_policy_numpy(
    path: str | Path,
) -> Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """A NumPy-only ``act(obs (M, D), mask (M,)) -> (accel (M,), lane (M,))``;
    ``lane`` is the environment's lane column (`jaxround.envs.lane_view`):
    1.0 (the lane to the left) or -1.0 (right) where the network changes
    lanes, NaN (no request) where it keeps."""
    arrays, layout = load_policy(path)

    def act(obs: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        obs = np.asarray(obs, np.float32)
        if obs.shape[-1] != layout.obs_size:
            raise ValueError(
                f"observation rows have {obs.shape[-1]} numbers, the policy reads "
                f"{layout.obs_size} ({layout.observer!r} observer)"
            )
        accel, change = policy_action(arrays, layout, obs, mask, np)
        return accel, networks.lane_column(change, np)

    return act


def check_finite(arrays: dict[str, Any], where: str) -> None:
    """Refuse weights holding NaN or infinity (a diverged run's, or a damaged
    file's): such a policy would drive nothing and look like no policy.

    Raises:
        ValueError: naming `where`, the first array with such values, and how
            many it holds.
    """
    for name in sorted(arrays):
        values = np.asarray(arrays[name])
        bad = int(np.sum(~np.isfinite(values)))
        if bad:
            raise ValueError(
                f"{where}: array {name!r} holds {bad} non-finite value(s) "
                f"(NaN or infinity) of {values.size}; refusing the policy"
            )


def _check_shapes(arrays: dict[str, Any], layout: PolicyLayout, where: str) -> None:
    for name, shape in layout.array_shapes().items():
        if name not in arrays:
            raise ValueError(f"{where}: array {name!r} is missing")
        if tuple(np.shape(arrays[name])) != shape:
            raise ValueError(
                f"{where}: {name} has shape {tuple(np.shape(arrays[name]))}, "
                f"the layout says {shape}"
            )


__all__ = [
    "FORMAT",
    "check_finite",
    "check_scenario",
    "POLICY_STEM",
    "PolicyLayout",
    "action_bounds",
    "export_policy",
    "load_policy",
    "load_policy_numpy",
    "policy_action",
    "policy_layout",
    "policy_paths",
]
