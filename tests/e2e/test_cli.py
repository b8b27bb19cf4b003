"""The `jaxround` command: JSON output, errors before work, nothing overwritten."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from jaxround.apps.cli.arguments import percent_list
from jaxround.apps.cli.main import main
from tests.conftest import builtin_dict


def small_config_file(tmp_path: Path, n: int = 100) -> Path:
    d = builtin_dict("milan")
    d["demand"].update(n_vehicles=n, duration_s=300.0)
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def test_percent_list() -> None:
    assert percent_list("0,10,...,100") == [i / 10 for i in range(11)]
    assert percent_list("50,0") == [0.0, 0.5]
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match="percentage"):
        percent_list("0,150")


@pytest.mark.sumo
def test_sumo_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = small_config_file(tmp_path)
    code = main(
        [
            "sumo",
            "--config",
            str(cfg),
            "--penetration",
            "10",
            "--seeds",
            "2",
            "--json",
            "--no-progress",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["per_seed"]) == 2
    mean = out["mean"]
    for cls in ("all", "hv", "av"):
        for key in (
            "n_departed",
            "n_arrived",
            "mean_crossing_time_s",
            "co2_g_per_veh",
            "fuel_g_per_veh",
            "consumption_score",
            "emission_score",
        ):
            assert key in mean[cls]
    assert mean["all"]["n_departed"] == 100
    assert mean["av"]["n_vehicles"] == 10
    assert {"collisions", "emergency_brakings", "teleports"} <= set(mean)


@pytest.mark.sumo
def test_scenario_refuses_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "scn"
    assert main(["scenario", "--out", str(out), "--penetration", "20"]) == 0
    net = out / "milan.net.xml"
    before = net.read_bytes()
    assert main(["scenario", "--out", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err
    assert net.read_bytes() == before
    assert main(["scenario", "--out", str(out), "--force"]) == 0


def test_bad_config_fails_before_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = builtin_dict("milan")
    d["demand"]["od"][0] = [0.0, 0.5, 0.2, 0.2]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(d))
    assert main(["sumo", "--config", str(bad), "--json"]) == 2
    err = capsys.readouterr().err
    assert "demand.od[0]: sums to 0.9, expected 1" in err
    with pytest.raises(SystemExit):
        main(["sumo", "--penetration", "140"])


def test_main_job_trains_on_the_scenario_it_evaluates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without --train-config the main job trains ppo_milan's recipe (one
    lane) or ppo_two_lane's (two lanes) on --config, a file by its absolute
    path; a --train-config on other roads is refused before any training,
    and nothing is written."""
    from jaxround.apps.cli.training import main_job_training
    from jaxround.scenario.config import load_config

    train, _ = main_job_training(None, load_config(None), None)
    assert train.scenario == "milan" and train.observer == ""
    train, _ = main_job_training("three_leg", load_config("three_leg"), None)
    assert train.scenario == "three_leg"
    two = tmp_path / "my_two_lane.yaml"
    two.write_text(yaml.safe_dump(builtin_dict("two_lane")))
    train, _ = main_job_training(str(two), load_config(two), None)
    assert train.scenario == str(two.resolve()) and train.observer == "lanes"
    out = tmp_path / "out"
    argv = ["run", "--config", "three_leg", "--train-config", "ppo_milan"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "trains on scenario 'milan'" in err and "--config 'three_leg'" in err
    assert not out.exists()


def test_bench_flags_fail_before_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "none.npz"
    argv = ["bench", "--json", "--no-progress", "--policy", str(missing)]
    assert main([*argv, "--no-training"]) == 2
    assert "--policy: not with --no-training" in capsys.readouterr().err
    assert main(argv) == 2
    assert f"policy file {missing} does not exist" in capsys.readouterr().err
    assert main(["bench", "--json", "--train-config", str(tmp_path / "x.yaml")]) == 2
    assert "x.yaml" in capsys.readouterr().err
    assert main(["bench", "--profile", "--policy", str(missing)]) == 2
    assert "not with --profile" in capsys.readouterr().err


@pytest.mark.sumo
def test_parity_redoes_runs_whose_slots_overflow(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 4 slots for 12 vehicles in a minute: insertions wait for a slot, so the
    # JAX run is redone with 8 slots, which hold them; stderr says so, the
    # JSON carries every M tried and no overflow
    d = builtin_dict("milan")
    d["demand"].update(n_vehicles=12, duration_s=60.0)
    d["simulation"]["max_vehicles"] = 8  # the config's, overridden by the flag
    path = tmp_path / "tight.yaml"
    path.write_text(yaml.safe_dump(d))
    argv = ["parity", "--config", str(path), "--seeds", "1", "--max-vehicles", "4",
            "--workers", "1", "--json", "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    tried = report["max_vehicles_tried"]
    assert tried == [4, 8] and report["max_vehicles"] == 8
    assert report["jax_slot_overflow"] == 0
    assert "max_vehicles = 4; redone with 8 slots" in captured.err


@pytest.mark.sumo
def test_parity_names_runs_with_vehicles_outside_at_the_cap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 40 vehicles in 60 s and no time to drain: both simulators leave
    # vehicles outside at the cap; the command names the runs on stderr and
    # in the JSON, and compares only the vehicles arrived in both
    d = builtin_dict("milan")
    d["demand"].update(n_vehicles=40, duration_s=60.0)
    d["simulation"]["max_vehicles"] = 32  # not sized from the traffic first
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(d))
    argv = ["parity", "--config", str(path), "--seeds", "2", "--drain-s", "0",
            "--workers", "1", "--json", "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["cap_s"] == 60.0
    outside = report["outside_at_cap"]
    assert {r["sim"] for r in outside} == {"jax", "sumo"}
    assert (
        sum(r["not_arrived"] for r in outside if r["sim"] == "jax")
        == (report["jax_not_arrived"])
    )
    assert "vehicles still outside at the cap (60 s)" in captured.err
    for r in outside:
        assert f"{r['sim'].upper()} seed {r['seed']}: {r['not_arrived']}" in (
            captured.err
        )
    assert "--drain-s" in captured.err
    # means over the same vehicles on both sides, fewer than either run's own
    jax_all, sumo_all = report["jax"]["all"], report["sumo"]["all"]
    assert jax_all["n_compared"] == sumo_all["n_compared"]
    assert report["n_compared"] == 2 * jax_all["n_compared"]
    assert jax_all["n_compared"] <= min(jax_all["n_arrived"], sumo_all["n_arrived"])
    assert jax_all["n_compared"] < jax_all["n_vehicles"]
    # the errors schedule by schedule, with their mean and interval
    by_seed = report["rel_err_by_seed"]["mean_crossing_time_s"]
    assert len(by_seed["per_seed"]) == 2
    assert by_seed["mean"] == pytest.approx(np.mean(by_seed["per_seed"]))
    assert by_seed["ci95"][0] <= by_seed["mean"] <= by_seed["ci95"][1]
    # past capacity: entry rates per leg and quantiles, with intervals
    rates = report["saturation"]["entry_rate_veh_per_h"]
    assert len(rates["jax"]["mean"]) == 4 and len(rates["jax"]["per_seed"]) == 2
    assert all(ci is not None for ci in rates["diff"]["ci95"])
    quantiles = report["saturation"]["crossing_time_quantiles_s"]
    assert quantiles["sumo"]["mean"][0] <= quantiles["sumo"]["mean"][2]
