"""A policy evaluated in SUMO: the sweep over penetrations and its report."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from sumo_export.controller import PolicyControllerFactory
from sumo_export.evaluate import sumo_policy_sweep
from sumo_export.policy_report import CONTROLLER_COLUMNS, write_policy_report
from tests.conftest import small_config
from tests.sumo.test_controller import write_standin_policy


def test_a_policy_of_another_observer_size_is_refused(tmp_path: Path) -> None:
    cfg = small_config("milan", n_vehicles=20, duration_s=60.0)
    policy = write_standin_policy(tmp_path, observer="rich", obs_size=10)
    with pytest.raises(ValueError, match="reads 10 numbers"):
        sumo_policy_sweep(cfg, policy, [1.0], [0], show_progress=False)


def test_the_controller_factory_pickles(tmp_path: Path) -> None:
    import pickle

    factory = PolicyControllerFactory(str(tmp_path / "policy.npz"), 48)
    assert pickle.loads(pickle.dumps(factory)) == factory


@pytest.mark.sumo
def test_policy_sweep_in_worker_processes_and_its_report(tmp_path: Path) -> None:
    cfg = small_config("milan", n_vehicles=40, duration_s=100.0)
    policy = write_standin_policy(tmp_path, bias=1.0)
    sweep = sumo_policy_sweep(
        cfg, policy, [0.0, 1.0], [0], workers=2, show_progress=False
    )
    dt = cfg.simulation.dt_s
    for result in sweep.values():
        mean, (run,) = result["mean"], result["per_seed"]
        timing = mean["controller"]
        assert timing["steps"] == round(run["sim_end_s"] / dt)
        assert 0 < timing["median_ms"] <= timing["p99_ms"]
        assert timing["overflow_vehicle_steps"] == 0
        assert mean["all"]["n_arrived"] == 40
        assert mean["collisions"] == 0
    assert sweep[0.0]["mean"]["controller"]["commands"] == 0
    assert sweep[1.0]["mean"]["controller"]["commands"] > 0
    assert sweep[1.0]["mean"]["av"]["n_vehicles"] == 40

    jax_like = {p: r["mean"] for p, r in sweep.items()}
    out = tmp_path / "report"
    markdown = write_policy_report(cfg, sweep, out, policy, jax_results=jax_like)
    assert "Table 3" in markdown and "controller median" in markdown
    # Eq. 5 on one scale over the sweep, and the table says so
    assert all(r["mean"]["score_scale"] == "sweep" for r in sweep.values())
    assert "one scale" in (out / "sumo_policy_table4.md").read_text()
    for name in ("table3", "table4", "absolute", "controller"):
        assert (out / f"sumo_policy_{name}.md").is_file()
        rows = list(csv.reader((out / f"sumo_policy_{name}.csv").open()))
        assert len(rows) == 3  # header and two penetrations
    header = next(csv.reader((out / "sumo_policy_controller.csv").open()))
    assert tuple(header) == CONTROLLER_COLUMNS
    saved = json.loads((out / "sumo_policy.json").read_text())
    assert set(saved["sumo"]) == {"0", "100"} and set(saved["jax"]) == {"0", "100"}
    assert saved["sumo"]["100"]["mean"]["controller"]["commands"] > 0
    assert (out / "sumo_policy.png").stat().st_size > 10_000
