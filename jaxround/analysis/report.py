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
    "collisions",
    "emergency brakings",
    "teleports",
)


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


def table_rows(summary: dict[float, dict[str, Any]]) -> dict[str, list[list[str]]]:
    """Rows of the three tables from ``{penetration: {"all": M, "hv": M, "av": M}}``."""
    t3, t4, ab = [], [], []
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
                _count(m.get("collisions")),
                _count(m.get("emergency_brakings")),
                _count(m.get("teleports")),
            ]
        )
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


def write_tables(
    summary: dict[float, dict[str, Any]], out_dir: Path, prefix: str
) -> str:
    """Write `<prefix>_table3.{md,csv}`, `_table4`, `_absolute`; return the Markdown."""
    rows = table_rows(summary)
    parts = []
    specs = (
        ("table3", TABLE3_COLUMNS, "Mean crossing time (s), the paper's Table 3"),
        ("table4", TABLE4_COLUMNS, "Consumption and emission scores, Table 4"),
        ("absolute", ABSOLUTE_COLUMNS, "Absolute CO2 and fuel, arrivals and safety"),
    )
    for key, cols, title in specs:
        md = markdown_table(cols, rows[key])
        (out_dir / f"{prefix}_{key}.md").write_text(f"### {title}\n\n{md}")
        (out_dir / f"{prefix}_{key}.csv").write_text(csv_table(cols, rows[key]))
        parts.append(f"### {title}\n\n{md}")
    return "\n".join(parts)


def write_json(obj: Any, path: Path) -> None:
    """Write JSON atomically (a crash leaves the old file, never half a new one)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    tmp.replace(path)
