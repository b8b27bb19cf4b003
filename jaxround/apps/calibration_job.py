"""The `jaxround calibrate` job: fit in JAX, run the fits back in SUMO, write files.

Writes calibration.json, hv_vtype.xml, fitted.yaml and calibration.png into
the output folder (see :func:`run_calibration`); the fitting itself is in
:mod:`jaxround.analysis.calibrate`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import yaml

from jaxround.analysis.calibrate import (
    fit_black_box,
    fit_gradient,
    make_problem,
    survey_loss,
)
from jaxround.analysis.survey import MEASURES, Survey
from jaxround.scenario.config import ScenarioConfig


def _unstack(tree: Any, n: int) -> list[Any]:
    return [jax.tree.map(lambda x, i=i: x[i], tree) for i in range(n)]


def survey_errors(sim: Survey, target: Survey) -> dict[str, float]:
    """Relative error of each table's mean (sim vs target), and the worst
    per-cell absolute error of the mean queue."""
    out = {}
    for name in MEASURES:
        t = float(np.mean(getattr(target, name)))
        s = float(np.mean(getattr(sim, name)))
        out[name] = abs(s - t) / max(abs(t), 1e-9)
    out["queue_mean_veh_max_cell_abs"] = float(
        np.max(np.abs(sim.queue_mean_veh - target.queue_mean_veh))
    )
    return out


def run_calibration(
    cfg: ScenarioConfig,
    survey: Survey,
    names: Sequence[str],
    out: Path,
    *,
    starts: int = 4,
    iters: int = 30,
    temperature: float = 0.5,
    learning_rate: float = 0.05,
    black_box: bool = True,
    check_sumo: bool = True,
    workers: int | None = None,
    progress: bool = True,
    seed: int = 0,
) -> dict[str, Any]:
    """The whole `jaxround calibrate` job; writes into `out`:

    - calibration.json: fitted values, errors, budgets, wall times, histories,
      "max_vehicles" and "jax_slot_overflow" (of the fits' exact JAX runs),
      and "chosen": the fit written below, the one with the lowest loss in the
      SUMO re-run ("chosen_by": "sumo_loss"), or in JAX without it;
    - hv_vtype.xml: the human drivers' SUMO vType with the chosen values;
    - fitted.yaml: the scenario with the chosen values (for `measure`, `sumo`);
    - calibration.png: loss against simulated seconds for both methods.
    """
    from jaxround.analysis.survey import jax_survey
    from jaxround.envs.roundabout import make
    from sumo_export.scenario import vtype_xml

    env, params = make(cfg)
    problem = make_problem(env, params, survey, names)
    key = jax.random.PRNGKey(seed)
    result: dict[str, Any] = {
        "scenario": cfg.name,
        "params": list(names),
        "start_values": problem.values(np.zeros(len(names))),
        "target_drivers": survey.drivers,
        "seeds": list(survey.seeds),
        "n_slots": survey.n_slots,
        "temperature": temperature,
        "max_vehicles": env.max_vehicles,
    }
    fits = {"gradient": fit_gradient(
        problem, key, n_starts=starts, n_iters=iters, learning_rate=learning_rate,
        temperature=temperature, progress=progress,
    )}  # fmt: skip
    if black_box:
        # the same budget of simulated seconds, spent on generations of up to 8
        population = max(2, min(8, starts * iters))
        gens = max(1, round(starts * iters / population))
        fits["black_box"] = fit_black_box(
            problem, key, population=population, n_iters=gens, progress=progress
        )
    for name, fit in fits.items():
        fitted = cfg.with_human_drivers(**fit["values"])
        fit_params = problem.params.replace(
            **{k: jnp.float32(v) for k, v in fit["values"].items()}
        )
        sim = jax_survey(
            env, fit_params, list(_unstack(problem.schedules, problem.n_runs)),
            survey.seeds, survey.n_slots, survey.slot_s,
        )  # fmt: skip
        fit["jax_errors"] = survey_errors(sim, survey)
        fit["jax_slot_overflow"] = sim.slot_overflow
        if check_sumo:
            from sumo_export.measure import sumo_survey

            back = sumo_survey(
                fitted, survey.seeds, survey.n_slots, survey.slot_s, workers=workers
            )
            fit["sumo_errors"] = survey_errors(back, survey)
            fit["sumo_loss"] = survey_loss(back, survey)
        if survey.drivers:
            fit["param_errors"] = {
                k: abs(v - survey.drivers[k]) / abs(survey.drivers[k])
                for k, v in fit["values"].items()
                if k in survey.drivers and survey.drivers[k]
            }
    result["fits"] = fits
    result["jax_slot_overflow"] = sum(f["jax_slot_overflow"] for f in fits.values())
    # the files carry the fit that reproduces the targets best: in SUMO where
    # the fits were run back there, else in JAX (a low JAX loss can come from
    # fitting JAX's own departures from SUMO)
    by = "sumo_loss" if check_sumo else "loss_exact"
    chosen = min(fits, key=lambda name: fits[name][by])
    result["chosen"], result["chosen_by"] = chosen, by
    fitted_cfg = cfg.with_human_drivers(**fits[chosen]["values"])
    (out / "hv_vtype.xml").write_text(
        vtype_xml("hv", fitted_cfg.drivers.hv, cfg.simulation.dt_s) + "\n"
    )
    plain = json.loads(json.dumps(fitted_cfg.to_dict()))
    (out / "fitted.yaml").write_text(yaml.safe_dump(plain, sort_keys=False))
    (out / "calibration.json").write_text(json.dumps(result, indent=1) + "\n")
    plot_calibration(fits, out / "calibration.png")
    return result


def plot_calibration(fits: dict[str, dict[str, Any]], path: Path) -> None:
    """Best loss against simulated seconds, one line per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    measured = {"gradient": "relaxed loss", "black_box": "exact loss"}
    for name, fit in fits.items():
        h = fit["history"]
        label = f"{name}, {measured.get(name, 'loss')} ({fit['wall_s']:.0f} s wall)"
        (line,) = ax.plot(
            [x["sim_s"] / 3600 for x in h], [x["loss"] for x in h], label=label
        )
        ax.scatter(  # what the fitted values give under the exact dynamics
            [h[-1]["sim_s"] / 3600], [fit["loss_exact"]], marker="x",
            color=line.get_color(), label=f"{name}: exact loss of its fit",
        )  # fmt: skip
    ax.set_xlabel("simulated hours")
    ax.set_ylabel("survey loss (best so far)")
    ax.set_yscale("log")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
