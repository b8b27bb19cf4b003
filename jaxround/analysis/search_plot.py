"""The figure of `jaxround search`: crossing time against CO2 per vehicle."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def plot_front(result: dict[str, Any], path: Path) -> None:
    """Every constant scored in the search (grey), their front (line), and on
    the evaluation seeds the AV vType uncontrolled, the best constant and the
    state-dependent controller; written to `path` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["scored"]
    t, c = np.asarray(s["time_s"]), np.asarray(s["co2_g"])
    ok = np.isfinite(t) & np.isfinite(c) & (t < np.nanpercentile(t, 95) * 1.5)
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    ax.scatter(t[ok], c[ok], s=8, c="0.7", label="constants tried (search seeds)")
    front = np.asarray(result["front"], int)
    ax.plot(t[front], c[front], "-o", ms=3, c="k", label="their front")
    marks = {"vtype": ("s", "AV vType, uncontrolled"),
             "constant": ("*", "best constant"),
             "state": ("D", "state-dependent controller")}  # fmt: skip
    for key, (marker, label) in marks.items():
        e = result["eval"][key]
        ax.scatter(
            e["time_s"], e["co2_g"], marker=marker, s=80,
            label=f"{label} (eval seeds): {e['objective']:.2f}",
        )  # fmt: skip
    w = result["objective"]
    ax.set_xlabel("mean crossing time per vehicle, s")
    ax.set_ylabel("mean CO2 per vehicle, g")
    ax.set_title(
        f"{result['scenario']}, {result['penetration']:.0%} AVs, "
        f"{result['n_vehicles']} vehicles in {result['window_s']:.0f} s; "
        f"objective {w['time_weight']:g} s + {w['co2_weight']:g} g",
        fontsize=9,
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
