"""The headroom study's table and figure (`jaxround.apps.headroom`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any


def conflicts(paired: dict[str, Any]) -> str:
    """The variant's conflicts per 1,000 vehicles of a paired difference."""
    d = paired.get("conflicts_per_1000_veh")
    return "-" if d is None else f"{d['policy']:.1f}"


def table(entries: Sequence[dict[str, Any]]) -> str:
    """A Markdown table: SUMO's paired differences (% of the AV vType) with
    the half widths of their 95% intervals over seeds and over vehicles, and
    JAX's differences beside."""

    def cell(d: dict[str, Any]) -> str:
        """Difference in % of the baseline, half widths of both intervals."""
        pct = 100.0 / d["baseline"]
        half = [
            "" if ci is None else f" ±{(ci[1] - ci[0]) / 2 * pct:.1f}"
            for ci in (d["ci95_seeds"], d["ci95_vehicles"])
        ]
        return f"{d['diff'] * pct:+.1f}{half[0]} /{half[1]}"

    lines = [
        "| AVs | variant | SUMO time s | SUMO time %, ±95% seeds / vehicles "
        "| SUMO CO2 g | SUMO CO2 % | JAX time % | JAX CO2 % "
        "| conflicts per 1,000 veh SUMO / JAX "
        "| SUMO collisions / emergency brakings |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for e in entries:
        s, j = e["sumo"], e["jax"]
        time_s, co2 = s["crossing_time_s"], s["co2_g"]
        lines.append(
            f"| {e['penetration']:.0%} | {e['variant']} | {time_s['policy']:.2f} "
            f"| {cell(time_s)} | {co2['policy']:.2f} | {cell(co2)} "
            f"| {100 * j['crossing_time_s']['rel_diff']:+.1f} "
            f"| {100 * j['co2_g']['rel_diff']:+.1f} "
            f"| {conflicts(s)} / {conflicts(j)} "
            f"| {e['sumo_collisions']} / {e['sumo_emergency_brakings']} |"
        )
    return "\n".join(lines)


def plot(
    entries: Sequence[dict[str, Any]],
    sweep: dict[str, Sequence[float]],
    base: dict[str, float],
    path: Path,
) -> None:
    """Time against CO2 per vehicle, one panel per penetration: each swept
    field a line through its values and the AV vType's (SUMO solid, JAX
    dashed), the envelope a diamond, scripted controllers crosses.

    Args:
        entries: `jaxround.apps.headroom.summarise`'s entries.
        sweep: field -> values swept (`jaxround.apps.headroom.SWEEP`).
        base: field -> the AV vType's own value.
        path: the PNG to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def xy(d: dict[str, Any]) -> tuple[float, float]:
        return d["crossing_time_s"]["policy"], d["co2_g"]["policy"]

    penetrations = sorted({e["penetration"] for e in entries}, reverse=True)
    fig, axes = plt.subplots(1, len(penetrations), figsize=(13, 5.5), squeeze=False)
    colors = dict(zip(sweep, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for ax, p in zip(axes[0], penetrations, strict=True):
        at = [e for e in entries if e["penetration"] == p]
        for sim, style, fill in (("sumo", "-", None), ("jax", "--", "none")):
            point = {e["variant"]: xy(e[sim]) for e in at}
            sumo = sim == "sumo"
            for field, values in sweep.items():
                curve = {v: point[f"{field}={v:g}"] for v in values}
                curve[base[field]] = point["vtype"]
                ax.plot(*zip(*(curve[v] for v in sorted(curve))), style, marker="o",
                        ms=4, mfc=fill, color=colors[field],
                        label=field if sumo else None)  # fmt: skip
                for v in values if sumo else ():
                    ax.annotate(f"{v:g}", curve[v], fontsize=7, color=colors[field],
                                xytext=(3, -9), textcoords="offset points")  # fmt: skip
            ax.plot(*point["envelope"], "D", color="k", mfc=fill,
                    label="envelope" if sumo else None)  # fmt: skip
            ax.plot(*point["vtype"], "*", ms=15, color="k",
                    mfc="gold" if sumo else "none",
                    label="AV vType" if sumo else None)  # fmt: skip
        for e in at:
            if e["controller"]:
                ax.plot(*xy(e["jax"]), "+", color="crimson", ms=9, alpha=0.6)
                ax.plot(*xy(e["sumo"]), "x", color="crimson", ms=8)
                ax.annotate(e["variant"], xy(e["sumo"]), fontsize=7, color="crimson",
                            xytext=(3, 3), textcoords="offset points")  # fmt: skip
        ax.set_title(f"{p:.0%} AVs: SUMO solid, JAX dashed/hollow; "
                     "scripted: x SUMO, + JAX", fontsize=10)  # fmt: skip
        ax.set_xlabel("mean crossing time, all vehicles (s)")
        ax.set_ylabel("CO2 per vehicle, all vehicles (g)")
        ax.grid(alpha=0.3)
    axes[0][-1].legend(
        fontsize=8, title="AV vType field swept", title_fontsize=8, loc="lower right"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
