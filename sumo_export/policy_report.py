"""Tables, JSON and figure of a policy evaluated in SUMO (`sumo_policy_sweep`).

    sweep = sumo_policy_sweep(cfg, "runs/ppo/policy", [0, 0.5, 1], [0, 1])
    write_policy_report(cfg, sweep, "runs/ppo/sumo", policy_path="runs/ppo/policy")

writes into the folder, with the prefix ``sumo_policy``:

- ``_table3.{md,csv}``: mean crossing time of AVs and HVs with their counts
  (the paper's Table 3);
- ``_table4.{md,csv}``: consumption and emission scores of AVs and HVs
  (Table 4);
- ``_absolute.{md,csv}``: CO2 and fuel g/veh, arrivals, collisions,
  emergency brakings, teleports;
- ``_controller.{md,csv}``: fuel g/veh per class and the controller's time
  per SUMO step (median, 99th percentile);
- ``sumo_policy.json``: all of it, per penetration;
- ``sumo_policy.png``: emission score, consumption score and crossing time
  against penetration (the paper's Figure 3), JAX beside SUMO when given.

The first three tables are `jaxround.analysis.report.write_tables`' own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jaxround.analysis.plots import plot_sweep
from jaxround.analysis.report import (
    csv_table,
    markdown_table,
    percent_label,
    score_scale_of,
    write_json,
    write_tables,
)
from jaxround.scenario.config import ScenarioConfig

PREFIX = "sumo_policy"
CONTROLLER_COLUMNS = (
    "%AVs",
    "fuel g/veh AV",
    "fuel g/veh HV",
    "controller median (ms/step)",
    "controller p99 (ms/step)",
    "steps",
    "slot overflow (vehicle-steps)",
)


def controller_rows(means: dict[float, dict[str, Any]]) -> list[list[str]]:
    """Rows of `CONTROLLER_COLUMNS` from ``{penetration: sweep["mean"]}``."""

    def cell(x: float | None, digits: int) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    rows = []
    for p in sorted(means):
        m = means[p]
        c = m.get("controller") or {}
        rows.append(
            [
                percent_label(p),
                cell(m["av"]["fuel_g_per_veh"], 1),
                cell(m["hv"]["fuel_g_per_veh"], 1),
                cell(c.get("median_ms"), 3),
                cell(c.get("p99_ms"), 3),
                str(c.get("steps", "-")),
                str(c.get("overflow_vehicle_steps", "-")),
            ]
        )
    return rows


def write_policy_report(
    cfg: ScenarioConfig,
    sweep: dict[float, dict[str, Any]],
    out_dir: str | Path,
    policy_path: str | Path | None = None,
    jax_results: dict[float, dict[str, Any]] | None = None,
) -> str:
    """Write the tables, JSON and figure of a SUMO policy sweep.

    Args:
        cfg: the scenario.
        sweep: `sumo_export.evaluate.sumo_policy_sweep`'s result.
        out_dir: the folder (created if missing); earlier files of the same
            names are replaced.
        policy_path: the policy, recorded in the JSON.
        jax_results: ``{penetration: metrics}`` of the same policy in JAX
            (e.g. `agents.common.evaluation.evaluate_policy(...)["results"]["policy"]`),
            drawn beside SUMO and kept in the JSON.

    Returns:
        The tables as Markdown.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    means = {p: r["mean"] for p, r in sweep.items()}
    markdown = write_tables(means, out, PREFIX)
    title = "Fuel per class and the controller's time per SUMO step"
    rows = controller_rows(means)
    md = f"### {title}\n\n{markdown_table(CONTROLLER_COLUMNS, rows)}"
    (out / f"{PREFIX}_controller.md").write_text(md)
    (out / f"{PREFIX}_controller.csv").write_text(csv_table(CONTROLLER_COLUMNS, rows))
    seeds = len(next(iter(sweep.values()))["per_seed"]) if sweep else 0
    curves = {"sumo": means}
    if jax_results:
        curves["jax"] = jax_results
    plot_sweep(
        curves,
        out / f"{PREFIX}.png",
        f"{cfg.name}: AVs driven by the policy, {seeds} seed(s)",
        score_scale=score_scale_of(means),
    )
    write_json(
        {
            "scenario": cfg.name,
            "config_fingerprint": cfg.fingerprint(),
            "policy": None if policy_path is None else str(policy_path),
            "sumo": {percent_label(p): r for p, r in sweep.items()},
            "jax": (
                None
                if jax_results is None
                else {percent_label(p): m for p, m in jax_results.items()}
            ),
        },
        out / f"{PREFIX}.json",
    )
    return f"{markdown}\n{md}"
