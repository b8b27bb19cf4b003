"""Near-conflicts against the AVs' time gap and impatience, in both simulators.

`conflict_sweep` runs `jaxround parity` once per AV setting (the vType's
``tau`` and ``impatience``, every AV uncontrolled) and keeps, per setting,
the mean crossing time, CO2 per vehicle and conflicts per 1,000 vehicles of
JAX and of SUMO (SUMO's SSM device; `jaxround.core.surrogate_safety` in JAX).
`jaxround conflicts` prints it as a table; docs/safety.md shows it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from jaxround.apps.drivers import with_av_numbers
from jaxround.apps.parity import parity_report
from jaxround.scenario.config import ScenarioConfig

#: The (tau, impatience) settings of the sweep: tau 1 s (the AV vType), 0.75
#: and 0.5 s (the old action's bound), each with impatience 0, 0.5 and 1.
DEFAULT_SETTINGS: tuple[tuple[float, float], ...] = tuple(
    (tau, impatience) for tau in (1.0, 0.75, 0.5) for impatience in (0.0, 0.5, 1.0)
)
SIMULATORS = ("jax", "sumo")
#: Conflicts agree when within this share of SUMO's ...
CONFLICT_REL_TOLERANCE = 0.15
#: ... or within this many per 1,000 vehicles where SUMO counts fewer than 10.
CONFLICT_ABS_TOLERANCE = 2.0


def conflicts_agree(jax_value: float, sumo_value: float) -> bool:
    """The issue's parity bound for conflicts per 1,000 vehicles."""
    if sumo_value < 10.0:
        return abs(jax_value - sumo_value) <= CONFLICT_ABS_TOLERANCE
    return abs(jax_value - sumo_value) <= CONFLICT_REL_TOLERANCE * sumo_value


def conflict_sweep(
    cfg: ScenarioConfig,
    seeds: Sequence[int],
    penetration: float,
    settings: Sequence[tuple[float, float]] = DEFAULT_SETTINGS,
    workers: int | None = None,
    say: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """One row per (tau, impatience): both simulators' means over `seeds`.

    Returns:
        ``[{"tau", "impatience", "jax": {...}, "sumo": {...}, "agree": bool,
        "sumo_conflict_types": {...}}]`` with ``mean_crossing_time_s``,
        ``co2_g_per_veh`` and ``conflicts_per_1000_veh`` on each side (all
        vehicles), and "agree" the conflicts' parity bound.
    """
    rows = []
    for i, (tau, impatience) in enumerate(settings, 1):
        say(f"[{i}/{len(settings)}] tau {tau:g} s, impatience {impatience:g}")
        setting = with_av_numbers(cfg, {"tau": tau, "impatience": impatience})
        report = parity_report(
            setting, seeds, workers=workers, show_progress=False,
            penetration=penetration,
        )  # fmt: skip
        keep = ("mean_crossing_time_s", "co2_g_per_veh", "conflicts_per_1000_veh")
        sides = {sim: {k: report[sim]["all"][k] for k in keep} for sim in SIMULATORS}
        rows.append(
            {
                "tau": tau,
                "impatience": impatience,
                **sides,
                "agree": conflicts_agree(
                    sides["jax"]["conflicts_per_1000_veh"],
                    sides["sumo"]["conflicts_per_1000_veh"],
                ),
                "sumo_conflict_types": report["sumo_conflict_types"],
                "n_not_arrived": report["jax_not_arrived"] + report["sumo_not_arrived"],
            }
        )
    return rows


def sweep_table(rows: Sequence[dict[str, Any]]) -> str:
    """The sweep as a Markdown table."""
    lines = [
        "| tau (s) | impatience | crossing time JAX / SUMO (s) | CO2 JAX / SUMO "
        "(g/veh) | conflicts per 1,000 veh JAX / SUMO | within bound |",
        "|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        j, s = r["jax"], r["sumo"]
        lines.append(
            f"| {r['tau']:g} | {r['impatience']:g} | "
            f"{j['mean_crossing_time_s']:.2f} / {s['mean_crossing_time_s']:.2f} | "
            f"{j['co2_g_per_veh']:.1f} / {s['co2_g_per_veh']:.1f} | "
            f"{j['conflicts_per_1000_veh']:.1f} / {s['conflicts_per_1000_veh']:.1f} | "
            f"{'yes' if r['agree'] else 'NO'} |"
        )
    return "\n".join(lines)
