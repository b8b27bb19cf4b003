"""The main job's front: crossing time against CO2 per vehicle, per driver.

One panel per compared penetration (50% and 100% AVs): uncontrolled AVs,
the best constant setting and the policy, in SUMO and in JAX (means over the
same vehicles and seeds, `jaxround.apps.pipeline`), and on the panel of its
penetration the front of the constants the search scored (from the best
constant's file, on the search's own schedules: a shorter window and other
seeds, so it sits near, not on, the main job's points).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Result key suffix of each driver, its marker and name.
DRIVER_MARKS = {
    "_uncontrolled": ("o", "uncontrolled AVs"),
    "_best_constant": ("D", "best constant"),
    "": ("*", "policy"),
}
SIM_COLOURS = {"sumo": ("tab:blue", "SUMO"), "jax": ("tab:orange", "JAX")}
PANELS = ("50", "100")


def plot_main_front(result: dict[str, Any], path: Path) -> None:
    """Write the figure (module docstring) of a main job's `result` to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [p for p in PANELS if p in result.get("sumo", {})]
    fig, axes = plt.subplots(
        1, max(len(labels), 1), figsize=(6 * max(len(labels), 1), 4.8), squeeze=False
    )
    front = (result.get("best_constant") or {}).get("front") or {}
    front_label = None
    if front.get("points"):
        front_label = f"{100 * float(front.get('penetration', 1.0)):g}"
    for ax, label in zip(axes[0], labels, strict=False):
        if label == front_label:
            pts = sorted((p["time_s"], p["co2_g"]) for p in front["points"])
            ax.plot(
                *zip(*pts, strict=True), "-", marker=".", c="0.6",
                label="constant front of the search (its own schedules)",
            )  # fmt: skip
        for sim, (colour, sim_name) in SIM_COLOURS.items():
            for suffix, (marker, name) in DRIVER_MARKS.items():
                m = (result.get(sim + suffix) or {}).get(label, {}).get("all", {})
                t, c = m.get("mean_crossing_time_s"), m.get("co2_g_per_veh")
                if t is None or c is None:
                    continue
                ax.scatter(t, c, marker=marker, s=90 if marker == "*" else 50,
                           c=colour, edgecolors="k", linewidths=0.5,
                           label=f"{name} ({sim_name})")  # fmt: skip
        ax.set_xlabel("mean crossing time per vehicle (s)")
        ax.set_ylabel("CO2 per vehicle (g)")
        ax.set_title(f"{label}% AVs", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    seeds = len(result.get("seeds", []))
    fig.suptitle(
        f"{result.get('scenario', '')}: the policy, the best constant and "
        f"uncontrolled AVs, {seeds} seed(s)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
