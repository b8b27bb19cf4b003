"""The command line's argument types, shared options and output helpers.

Penetrations on the command line are percentages (0-100), as in the paper's
tables; in config files they are shares (0-1).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from jaxround.core.capacity import overflow_warning
from jaxround.scenario.best_constant import BestConstant
from jaxround.scenario.config import DRAIN_S, ScenarioConfig


class UsageError(ValueError):
    """A command-line value is wrong; reported without a traceback."""


def percent(text: str) -> float:
    """A penetration in percent -> share in [0, 1]."""
    try:
        x = float(text.rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= x <= 100.0:
        raise argparse.ArgumentTypeError(
            f"{text}: a penetration is a percentage, 0-100"
        )
    return x / 100.0


def percent_list(text: str) -> list[float]:
    """'0,10,...,100' or '0,50,100' -> shares."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if "..." in parts:
        i = parts.index("...")
        if i < 2 or i != len(parts) - 2:
            raise argparse.ArgumentTypeError("use 'a,b,...,z' with a step given by a,b")
        a, b, z = float(parts[0]), float(parts[1]), float(parts[-1])
        step = b - a
        if step <= 0:
            raise argparse.ArgumentTypeError(f"{text}: the step must be positive")
        values = []
        x = a
        while x <= z + 1e-9:
            values.append(x)
            x += step
        parts = [str(v) for v in values]
    shares = [percent(p) for p in parts]
    if not shares:
        raise argparse.ArgumentTypeError("no penetration given")
    return sorted(set(shares))


def positive_int(text: str) -> int:
    return _int_at_least(text, 1, "at least 1")


def non_negative_int(text: str) -> int:
    return _int_at_least(text, 0, "0 or more")


def _int_at_least(text: str, low: int, expected: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if x < low:
        raise argparse.ArgumentTypeError(f"{text}: expected {expected}")
    return x


def fresh_output_dir(path: Path, force: bool, would_write: Sequence[str]) -> Path:
    """Create `path`; refuse to overwrite any of `would_write` in it unless forced."""
    if path.exists() and not path.is_dir():
        raise UsageError(f"--out {path}: exists and is not a folder")
    clash = [name for name in would_write if (path / name).exists()]
    if clash and not force:
        raise UsageError(
            f"--out {path}: already holds {', '.join(clash)}; choose another folder "
            "or pass --force to overwrite"
        )
    path.mkdir(parents=True, exist_ok=True)
    return path


def seeds_of(cfg: ScenarioConfig, k: int) -> list[int]:
    """K consecutive seeds starting at the config's seed."""
    return [cfg.simulation.seed + i for i in range(k)]


def print_json(obj: object) -> None:
    json.dump(obj, sys.stdout, indent=2)
    sys.stdout.write("\n")


def workers_option(p: argparse.ArgumentParser) -> None:
    """--workers: SUMO processes side by side; --executor: where they run."""
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="SUMO processes side by side (default: CPUs)",
    )
    p.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="where the SUMO runs go: a local process pool (default) or a Ray "
        "cluster (RAY_ADDRESS, else a local one of --workers CPUs; "
        'pip install "jaxround[ray]")',
    )


def sumo_run_options(p: argparse.ArgumentParser) -> None:
    """--workers, --json and --no-progress of the commands that run SUMO."""
    workers_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def config_option(p: argparse.ArgumentParser) -> None:
    """--config: the scenario."""
    p.add_argument(
        "--config",
        default=None,
        help="scenario YAML file or built-in name (default: milan)",
    )


def slot_count(text: str) -> int | str:
    """A positive integer, or "road" (what the road holds)."""
    return text if text == "road" else positive_int(text)


def slots_option(p: argparse.ArgumentParser) -> None:
    """--max-vehicles: the JAX environment's vehicle slots M."""
    p.add_argument(
        "--max-vehicles", type=slot_count, default=None,
        help="JAX vehicle slots M, or 'road' for what the road holds (default: "
        "the scenario's simulation.max_vehicles, else what its traffic needs; "
        "a run whose slots overflow is redone with more)",
    )  # fmt: skip


def drain_option(p: argparse.ArgumentParser) -> None:
    """--drain-s: how long runs may go on after the demand horizon (the cap)."""
    p.add_argument(
        "--drain-s", type=nonnegative_seconds, default=DRAIN_S,
        help="simulated seconds after the demand horizon a run may go on for its "
        f"last vehicles, in both simulators (default {DRAIN_S:g}); raise it when "
        "vehicles are left outside at the cap",
    )  # fmt: skip


def score_scale_option(p: argparse.ArgumentParser) -> None:
    """--score-scale: Eq. 5's min and max over the sweep or per run."""
    p.add_argument(
        "--score-scale", choices=("sweep", "run"), default="sweep",
        help="Eq. 5 (consumption and emission scores): min and max over every "
        "run compared (sweep, the default: rows on one scale) or each run's own",
    )  # fmt: skip


def nonnegative_seconds(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not x >= 0.0 or x == float("inf"):
        raise argparse.ArgumentTypeError(f"{text}: expected 0 or more seconds")
    return x


def warn_outside_at_cap(result: dict[str, Any], what: str) -> None:
    """Name on stderr the runs of a result that left vehicles outside at the
    cap (``outside_at_cap``: ``[{"sim"?, "driver"?, "penetration"?, "seed",
    "not_arrived"}]``, ``cap_s``); say the means are over the vehicles
    arrived in every run compared, and how to raise the cap."""
    runs = result.get("outside_at_cap") or []
    if not runs:
        return
    names = []
    for r in runs:
        parts = [r.get("sim", "").upper(), r.get("driver", "")]
        if "penetration" in r:
            parts.append(f"{100 * r['penetration']:g}% AVs")
        parts.append(f"seed {r['seed']}: {r['not_arrived']}")
        names.append(" ".join(x for x in parts if x))
    print(
        f"{what}: vehicles still outside at the cap ({result.get('cap_s', 0):g} s) "
        f"in {len(runs)} run(s) [{'; '.join(names)}]; the means compare only the "
        "vehicles that arrived in every run compared; raise the cap with --drain-s",
        file=sys.stderr,
    )


def warn_slot_overflow(result: dict[str, Any], what: str) -> None:
    """Print `overflow_warning` to stderr for a JSON result that carries
    ``jax_slot_overflow`` and ``max_vehicles`` (parity, evaluation, bench);
    nothing when it has none."""
    text = overflow_warning(
        int(result.get("jax_slot_overflow") or 0), result.get("max_vehicles"), what
    )
    if text:
        print(text, file=sys.stderr)


def best_constant_option(p: argparse.ArgumentParser) -> None:
    """--best-constant: the constant AV setting evaluated beside a policy."""
    p.add_argument(
        "--best-constant", default=None, metavar="FILE|NAME|none",
        help="the best constant AV setting evaluated beside the policy: a file "
        "or a scenario's name (default: the scenario's own "
        "configs/best_constant/<scenario>.json, if it has one; none: skip it)",
    )  # fmt: skip


def best_constant_of(source: str | None, cfg: ScenarioConfig) -> BestConstant | None:
    """The best constant of `--best-constant` (a file or name; None: the
    scenario's own, if any; "none": none), checked against the scenario."""
    from jaxround.scenario.best_constant import builtin_path, load_best_constant
    from jaxround.scenario.config import ConfigError

    if source == "none" or (source is None and builtin_path(cfg.name) is None):
        return None
    try:
        constant = load_best_constant(cfg.name if source is None else source)
        constant.config_for(cfg)
    except ConfigError as err:
        raise UsageError(f"--best-constant: {err}") from None
    return constant
