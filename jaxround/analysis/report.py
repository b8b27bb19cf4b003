"""Tables (Markdown, CSV) in the form of the paper's Tables 3 and 4; JSON output."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

TABLE3_COLUMNS = ("%AVs", "mean AV (s)", "mean HV (s)", "#AVs", "#HVs")
TABLE4_COLUMNS = (
    "%AVs",
    "AV consumption",
    "AV emission",
    "HV consumption",
    "HV emission",
    "#AVs",
    "#HVs",
)
ABSOLUTE_COLUMNS = (
    "%AVs",
    "CO2 g/veh (all)",
    "fuel g/veh (all)",
    "CO2 g/veh AV",
    "CO2 g/veh HV",
    "arrived",
    "not arrived",
    "collisions",
    "emergency brakings",
    "teleports",
)
#: Lane changes per vehicle, where the runs counted them (two-lane roads).
LANE_CHANGES = "lane_changes_per_veh"
#: The absolute table's last columns on roads of two lanes.
LANE_CHANGE_COLUMNS = (
    "lane changes per veh (all)",
    "lane changes per veh AV",
    "lane changes per veh HV",
)
#: What the Table 4 title says of Eq. 5's scale.
SCALE_NOTE = {
    "sweep": "min and max over every run of the table (one scale)",
    "joint": "min and max over every run of JAX and SUMO, every driver (one scale)",
    "run": "min and max over each run's own vehicles (rows on different scales)",
}


def percent_label(p: float) -> str:
    """10 for 0.1; 12.5 for 0.125."""
    x = round(p * 100.0, 6)
    return str(int(x)) if float(x).is_integer() else str(x)


def _cell(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}f}"
    return str(x)


def _count(x: Any) -> str:
    """A count, or a mean of counts over seeds (one decimal when not whole)."""
    if x is None:
        return "-"
    return str(int(x)) if float(x).is_integer() else f"{x:.1f}"


def has_lane_changes(summary: dict[float, dict[str, Any]]) -> bool:
    """Whether the runs counted lane changes (roads of two lanes)."""
    return any(m["all"].get(LANE_CHANGES) is not None for m in summary.values())


def absolute_columns(summary: dict[float, dict[str, Any]]) -> tuple[str, ...]:
    """`ABSOLUTE_COLUMNS`, and `LANE_CHANGE_COLUMNS` where lanes were changed."""
    lanes = LANE_CHANGE_COLUMNS if has_lane_changes(summary) else ()
    return ABSOLUTE_COLUMNS + lanes


def table_rows(summary: dict[float, dict[str, Any]]) -> dict[str, list[list[str]]]:
    """Rows of the three tables from ``{penetration: {"all": M, "hv": M, "av": M}}``
    (the absolute table's as `absolute_columns`)."""
    t3, t4, ab = [], [], []
    lanes = has_lane_changes(summary)
    for p in sorted(summary):
        m = summary[p]
        av, hv, everyone = m["av"], m["hv"], m["all"]
        n_av, n_hv = round(av["n_vehicles"]), round(hv["n_vehicles"])
        label = percent_label(p)
        t3.append(
            [
                label,
                _cell(av["mean_crossing_time_s"]),
                _cell(hv["mean_crossing_time_s"]),
                str(n_av),
                str(n_hv),
            ]
        )
        t4.append(
            [
                label,
                _cell(av["consumption_score"]),
                _cell(av["emission_score"]),
                _cell(hv["consumption_score"]),
                _cell(hv["emission_score"]),
                str(n_av),
                str(n_hv),
            ]
        )
        ab.append(
            [
                label,
                _cell(everyone["co2_g_per_veh"], 1),
                _cell(everyone["fuel_g_per_veh"], 1),
                _cell(av["co2_g_per_veh"], 1),
                _cell(hv["co2_g_per_veh"], 1),
                _count(everyone["n_arrived"]),
                _count(everyone.get("n_not_arrived")),
                _count(m.get("collisions")),
                _count(m.get("emergency_brakings")),
                _count(m.get("teleports")),
            ]
        )
        if lanes:
            ab[-1] += [_cell(c.get(LANE_CHANGES)) for c in (everyone, av, hv)]
    return {"table3": t3, "table4": t4, "absolute": ab}


def markdown_table(columns: tuple[str, ...], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def csv_table(columns: tuple[str, ...], rows: list[list[str]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(columns)
    writer.writerows(rows)
    return buf.getvalue()


def score_scale_of(summary: dict[float, dict[str, Any]]) -> str:
    """The Eq. 5 scale a summary's rows carry ("score_scale"; "run" if none)."""
    scales = {m.get("score_scale", "run") for m in summary.values()}
    return scales.pop() if len(scales) == 1 else "run"


def compared_note(summary: dict[float, dict[str, Any]]) -> str:
    """A line for tables whose runs left vehicles outside at the cap ('' if
    none did): their means are over the vehicles arrived in every run."""
    left = [
        (p, m["all"].get("n_not_arrived") or 0)
        for p, m in sorted(summary.items())
        if m["all"].get("n_not_arrived")
    ]
    if not left:
        return ""
    rows = ", ".join(f"{percent_label(p)}% AVs: {_count(n)}" for p, n in left)
    return (
        f"Vehicles outside at the cap (mean per seed; {rows}): means are over "
        "the vehicles that arrived in every run compared.\n\n"
    )


def write_tables(
    summary: dict[float, dict[str, Any]],
    out_dir: Path,
    prefix: str,
    score_scale: str | None = None,
) -> str:
    """Write `<prefix>_table3.{md,csv}`, `_table4`, `_absolute`; return the Markdown.

    Args:
        score_scale: Eq. 5's scale the rows were computed on, named in Table
            4's title; None: the summary's own ("score_scale", `score_scale_of`).
    """
    rows = table_rows(summary)
    parts = []
    scale = score_scale or score_scale_of(summary)
    note = compared_note(summary)
    specs = (
        ("table3", TABLE3_COLUMNS, "Mean crossing time (s), the paper's Table 3"),
        (
            "table4", TABLE4_COLUMNS,
            f"Consumption and emission scores, Table 4 (Eq. 5: {SCALE_NOTE[scale]})",
        ),
        (
            "absolute", absolute_columns(summary),
            "Absolute CO2 and fuel, arrivals and safety"
            + (", lane changes" if has_lane_changes(summary) else ""),
        ),
    )  # fmt: skip
    for key, cols, title in specs:
        md = note + markdown_table(cols, rows[key])
        (out_dir / f"{prefix}_{key}.md").write_text(f"### {title}\n\n{md}")
        (out_dir / f"{prefix}_{key}.csv").write_text(csv_table(cols, rows[key]))
        parts.append(f"### {title}\n\n{md}")
    return "\n".join(parts)


def write_json(obj: Any, path: Path) -> None:
    """Write JSON atomically (a crash leaves the old file, never half a new one)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    tmp.replace(path)
