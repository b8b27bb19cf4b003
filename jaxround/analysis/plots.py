"""Figures: the penetration sweep in the manner of the paper's Figure 3."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PANELS = (
    ("emission_score", "emission score\n(Eq. 5{})"),
    ("consumption_score", "consumption score\n(Eq. 5{})"),
    ("mean_crossing_time_s", "mean crossing time (s)"),
)
#: How the score panels name Eq. 5's scale.
SCALE_LABEL = {
    "sweep": ", one scale over the sweep",
    "joint": ", one scale over JAX and SUMO",
    "run": ", each run its own",
}
CLASS_STYLE = {"av": ("tab:blue", "AVs"), "hv": ("tab:orange", "HVs")}
SIM_STYLE = {"sumo": ("-", "o"), "jax": ("--", "s")}


def plot_sweep(
    results: dict[str, dict[float, dict[str, Any]]],
    path: Path,
    title: str,
    score_scale: str = "run",
) -> None:
    """Emission, consumption and crossing time against AV penetration.

    Args:
        results: ``{simulator: {penetration: {"av": M, "hv": M, ...}}}`` with
            simulator "sumo" and/or "jax".
        path: the PNG to write.
        title: figure title.
        score_scale: Eq. 5's scale of the scores ("sweep", "joint" or
            "run"), named on the score panels. JAX beside SUMO is comparable
            on "joint" only (`jaxround.analysis.metrics.sweep_scale`).
    """
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True)
    for ax, (key, label) in zip(axes, PANELS, strict=True):
        for sim, by_p in results.items():
            line, marker = SIM_STYLE.get(sim, ("-", "."))
            for cls, (color, name) in CLASS_STYLE.items():
                pts = [
                    (100 * p, m[cls][key])
                    for p, m in sorted(by_p.items())
                    if m[cls][key] is not None
                ]
                if pts:
                    xs, ys = zip(*pts, strict=True)
                    ax.plot(
                        xs,
                        ys,
                        line,
                        marker=marker,
                        color=color,
                        label=f"{name} ({sim.upper()})",
                    )
        ax.set_xlabel("AV penetration (%)")
        ax.set_ylabel(label.format(SCALE_LABEL[score_scale]))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.savefig(path, dpi=120)
    plt.close(fig)
