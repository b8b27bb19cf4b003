"""What a search leaves for the main job: the best constant's versioned file.

`best_constant_file` turns `jaxround.apps.search.run_search`'s result into
the JSON of ``configs/best_constant/<scenario>.json``
(`jaxround.scenario.best_constant`): the setting, the objective it was found
for (with the constraint on conflicts and the AVs' time-gap floor, where the
search had them), the case, the command that regenerates it, and the front
of crossing time against CO2 of the constants scored.
"""

from __future__ import annotations

from typing import Any

from jaxround.analysis.setting_search import describe

#: The case's keys of a search result copied into the file's "found".
FOUND = ("penetration", "n_vehicles", "window_s", "origin_share", "min_av_tau_s",
         "conflict_limit_per_1000", "search_seeds", "eval_seeds", "budget")  # fmt: skip


def objective_description(result: dict[str, Any]) -> str:
    """The search's objective in words, e.g. ``1 per second of crossing
    time plus 0.5 per gram of CO2, ...``."""
    objective = result["objective"]
    words = (
        f"{objective['time_weight']:g} per second of crossing time plus "
        f"{objective['co2_weight']:g} per gram of CO2"
    )
    if objective.get("conflict_weight"):
        words += f" plus {objective['conflict_weight']:g} per near-conflict"
    words += ", mean over every vehicle"
    if objective.get("charge_exit"):
        words += ", with the exit debt"
    limit = result.get("conflict_limit_per_1000")
    if limit is not None:
        words += f", at most {limit:.4g} conflicts per 1,000 vehicles"
    floor = result.get("min_av_tau_s")
    if floor:
        words += f", tau at least {floor:g} s"
    return words + " (the system reward's weights)"


def best_constant_file(result: dict[str, Any], command: str) -> dict[str, Any]:
    """The best constant of a search's `result` as the versioned file's JSON,
    its front included.

    Args:
        result: `run_search`'s result.
        command: the ``jaxround search`` command that gave it.
    """
    scored = result["scored"]
    extra = [k for k in ("conflicts_per_1000",) if k in scored]
    return {
        "scenario": result["scenario"],
        "setting": result["best_constant"],
        "objective": {
            "description": objective_description(result),
            **result["objective"],
        },
        "found": {key: result[key] for key in FOUND if key in result},
        "command": command,
        "front": {
            "penetration": result["penetration"],
            "what": "search seeds, mean crossing time and CO2 per vehicle",
            "points": [
                {
                    "time_s": round(scored["time_s"][i], 4),
                    "co2_g": round(scored["co2_g"][i], 4),
                    "objective": round(scored["objective"][i], 4),
                    **{k: round(scored[k][i], 4) for k in extra},
                    "setting": describe(scored["settings"][i]),
                }
                for i in result["front"]
            ],
        },
    }
