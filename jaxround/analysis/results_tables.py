"""The main job's summary tables, from its ``results.json`` alone.

The main job (`jaxround.apps.pipeline`) writes these beside its other
tables, and `jaxround.apps.readme_tables` prints them for the README, so a
README's figures are what the code prints from a results file:

- Table 3 of the policy in SUMO (`report.table_rows`);
- the drivers side by side (`beside_rows`): the policy, the best constant
  setting and uncontrolled AVs, in SUMO and JAX, mean crossing time and CO2
  per vehicle at 0%, 50% and 100% AVs, and the human drivers at 50%
  (near-conflicts where counted, lane changes per vehicle on two lanes);
- the paired differences (`paired_rows`): policy minus uncontrolled, policy
  minus best constant, best constant minus uncontrolled, with 95% intervals
  over the seeds (`jaxround.analysis.compare`).

Rows of a driver the results lack (no best constant) are left out.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jaxround.analysis.report import (
    LANE_CHANGES,
    TABLE3_COLUMNS,
    csv_table,
    markdown_table,
    table_rows,
)

SIMULATORS = {"sumo": "SUMO", "jax": "JAX"}
#: Result key suffix of each driver and its name in the tables.
DRIVERS = {"": "policy", "_best_constant": "best constant", "_uncontrolled": (
    "uncontrolled AVs")}  # fmt: skip
#: Penetration labels of the side-by-side table; HVs at the middle one.
BESIDE_AT = ("0", "50", "100")
HV_AT = "50"
BESIDE_COLUMNS = ("", "0% AVs", "50% AVs", "100% AVs", "HVs at 50%")
#: (where in results.json, name): each paired difference.
PAIRS = (
    (("comparison",), "policy - uncontrolled AVs"),
    (("comparison_best_constant", "policy_vs_best_constant"),
     "policy - best constant"),
    (("comparison_best_constant", "best_constant_vs_uncontrolled"),
     "best constant - uncontrolled AVs"),
)  # fmt: skip
PAIRED_COLUMNS = (
    "",
    "%AVs",
    "crossing time",
    "95% interval (seeds)",
    "CO2",
    "95% interval (seeds)",
)
#: Near-conflicts per 1,000 vehicles (SUMO's SSM count and JAX's), where the
#: results have them: a last column in both tables.
CONFLICTS = "conflicts_per_1000_veh"
BESIDE_CONFLICTS = "conflicts per 1,000 vehicles, 0 / 50 / 100% AVs"
PAIRED_CONFLICTS = "conflicts per 1,000 vehicles"
#: Lane changes per vehicle (report.LANE_CHANGES), on roads of two lanes: the
#: side-by-side table's last column.
BESIDE_LANE_CHANGES = "lane changes per vehicle, 0 / 50 / 100% AVs"


def counted(result: dict[str, Any], key: str) -> bool:
    """Whether any run of the results has `key` for all vehicles (the
    conflicts where counted, the lane changes on two-lane roads)."""
    return any(
        m.get("all", {}).get(key) is not None
        for sim in SIMULATORS
        for suffix in DRIVERS
        for m in (result.get(sim + suffix) or {}).values()
    )


def has_conflicts(result: dict[str, Any]) -> bool:
    """Whether any run of the results counted near-conflicts."""
    return counted(result, CONFLICTS)


def at_shares(runs: dict[str, Any], key: str, digits: int) -> str:
    """``"0 / 5 / 12"``: `key` of all vehicles at `BESIDE_AT`'s shares."""
    values = [runs.get(label, {}).get("all", {}).get(key) for label in BESIDE_AT]
    return " / ".join("-" if v is None else f"{v:.{digits}f}" for v in values)


def beside_columns(result: dict[str, Any]) -> tuple[str, ...]:
    """`BESIDE_COLUMNS`, and the conflicts' and lane changes' where counted."""
    conflicts = (BESIDE_CONFLICTS,) if has_conflicts(result) else ()
    lanes = (BESIDE_LANE_CHANGES,) if counted(result, LANE_CHANGES) else ()
    return BESIDE_COLUMNS + conflicts + lanes


def paired_columns(result: dict[str, Any]) -> tuple[str, ...]:
    """`PAIRED_COLUMNS`, and the conflicts' where counted."""
    return PAIRED_COLUMNS + ((PAIRED_CONFLICTS,) if has_conflicts(result) else ())


def by_share(per_label: dict[str, Any]) -> dict[float, Any]:
    """``{"10": M}`` -> ``{0.1: M}``."""
    return {float(label) / 100.0: m for label, m in per_label.items()}


def beside_rows(result: dict[str, Any]) -> list[list[str]]:
    """Rows of `beside_columns`: per simulator, each driver present."""
    conflicts, lanes, rows = has_conflicts(result), counted(result, LANE_CHANGES), []
    for sim, sim_name in SIMULATORS.items():
        for suffix, driver in DRIVERS.items():
            runs = result.get(sim + suffix)
            if not runs:
                continue
            row = [f"{sim_name}, {driver}"]
            for label in BESIDE_AT:
                everyone = runs.get(label, {}).get("all", {})
                t, c = (
                    everyone.get("mean_crossing_time_s"),
                    everyone.get("co2_g_per_veh"),
                )
                row.append("-" if t is None or c is None else f"{t:.2f} s / {c:.1f} g")
            hv = runs.get(HV_AT, {}).get("hv", {}).get("mean_crossing_time_s")
            row.append("-" if hv is None else f"{hv:.2f} s")
            if conflicts:
                row.append(at_shares(runs, CONFLICTS, 0))
            if lanes:
                row.append(at_shares(runs, LANE_CHANGES, 2))
            rows.append(row)
    return rows


def _pair(result: dict[str, Any], where: tuple[str, ...]) -> dict[str, Any] | None:
    node: Any = result
    for key in where:
        node = node.get(key) if isinstance(node, dict) else None
    return node


def _difference(d: dict[str, Any] | None, unit: str) -> tuple[str, str]:
    """("-3.43 s (-18.9%)", "[-20.1, -17.6]%") of a paired difference."""
    if d is None:
        return "-", "-"
    text = f"{d['diff']:+.2f} {unit}"
    if d.get("rel_diff") is not None:
        text += f" ({100 * d['rel_diff']:+.1f}%)"
    ci, base = d.get("ci95_seeds"), d.get("baseline")
    if ci is None or not base:
        return text, "-"
    return text, f"[{100 * ci[0] / base:+.1f}, {100 * ci[1] / base:+.1f}]%"


def _count_difference(d: dict[str, Any] | None) -> str:
    """ "+33.8 (11.7 to 45.5)" of a paired difference of counts."""
    if d is None:
        return "-"
    return f"{d['diff']:+.1f} ({d['baseline']:.1f} to {d['policy']:.1f})"


def paired_rows(result: dict[str, Any]) -> list[list[str]]:
    """Rows of `paired_columns`: per simulator, pair and penetration, the
    mean difference of all vehicles' crossing time and CO2 (and conflicts)."""
    conflicts, rows = has_conflicts(result), []
    for sim, sim_name in SIMULATORS.items():
        for where, name in PAIRS:
            pair = _pair(result, where)
            for label, by_class in sorted(
                ((pair or {}).get(sim) or {}).items(), key=lambda kv: float(kv[0])
            ):
                every = by_class["all"]
                t, t_ci = _difference(every.get("crossing_time_s"), "s")
                c, c_ci = _difference(every.get("co2_g"), "g")
                row = [f"{sim_name}, {name}", label, t, t_ci, c, c_ci]
                if conflicts:
                    row.append(_count_difference(every.get(CONFLICTS)))
                rows.append(row)
    return rows


def table3_markdown(result: dict[str, Any], key: str = "sumo") -> str:
    """Table 3 (mean crossing time per class) of ``result[key]``."""
    return markdown_table(TABLE3_COLUMNS, table_rows(by_share(result[key]))["table3"])


def safety_line(result: dict[str, Any]) -> str:
    """Collisions and teleports in SUMO over every run, and SUMO's gain over
    uncontrolled AVs as a share of JAX's, in a sentence."""
    counts = {"collisions": 0, "teleports": 0}
    for suffix in DRIVERS:
        for m in (result.get("sumo" + suffix) or {}).values():
            for key in counts:
                counts[key] += int(m.get(key) or 0)
    gains = (result.get("comparison") or {}).get("sumo_to_jax_gain") or {}
    shares = ", ".join(
        f"{100 * g:.0f}% at {label}% AVs"
        for label, g in sorted(gains.items(), key=lambda kv: float(kv[0]))
        if g is not None
    )
    line = (
        f"SUMO, every run: {counts['collisions']} collisions, "
        f"{counts['teleports']} teleports."
    )
    if shares:
        line += (
            " The policy's gain over uncontrolled AVs in SUMO (mean crossing "
            f"time), as a share of its gain in JAX: {shares}."
        )
    return line + "\n"


def readme_markdown(result: dict[str, Any]) -> str:
    """The README's block of results: Table 3 of the policy in SUMO, the
    drivers side by side, the paired differences; Markdown."""
    seeds = ", ".join(str(s) for s in result.get("seeds", []))
    best = result.get("best_constant")
    constant = ""
    if best:
        numbers = ", ".join(
            f"{k} {'none' if v is None else f'{v:g}'}"
            for k, v in best["setting"].items()
        )
        objective = best["objective"].get("description", "the training objective")
        constant = (
            f"The best constant (`{best.get('source') or 'best constant'}`), the "
            f"same for every AV at every step: {numbers}; found by `jaxround "
            f"search` for the objective {objective}.\n\n"
        )
    return (
        f"Table 3 in SUMO, AVs driven by the exported policy (schedule seeds "
        f"{seeds}):\n\n{table3_markdown(result)}\n"
        "The policy beside the best constant setting and beside uncontrolled AVs "
        "of the same vType, same schedules, both simulators (mean crossing time "
        "of all vehicles / CO2 per vehicle; HVs at 50%):\n\n"
        f"{markdown_table(beside_columns(result), beside_rows(result))}\n{constant}"
        "Paired on the same vehicles (mean over the seeds of each schedule's "
        "difference; intervals relative to the second driver):\n\n"
        f"{markdown_table(paired_columns(result), paired_rows(result))}\n"
        f"{safety_line(result)}"
    )


def write_results_tables(result: dict[str, Any], out: Path) -> None:
    """Write ``beside.{md,csv}``, ``paired.{md,csv}`` and ``readme_tables.md``
    (`readme_markdown`) into `out`."""
    for name, columns, rows in (
        ("beside", beside_columns(result), beside_rows(result)),
        ("paired", paired_columns(result), paired_rows(result)),
    ):
        (out / f"{name}.md").write_text(markdown_table(columns, rows))
        (out / f"{name}.csv").write_text(csv_table(columns, rows))
    (out / "readme_tables.md").write_text(readme_markdown(result))
