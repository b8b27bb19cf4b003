"""The traffic survey (targets of `jaxround calibrate`): SUMO and JAX agree,
files round-trip, bad files and arguments get clear errors."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from jaxround.analysis.calibrate import parse_param_names, survey_loss
from jaxround.analysis.survey import MEASURES, jax_survey, load_survey
from jaxround.apps.cli.main import main
from jaxround.envs.roundabout import make
from jaxround.scenario.config import ConfigError
from jaxround.scenario.schedule import make_schedule
from sumo_export.measure import sumo_survey
from tests.conftest import small_config


@pytest.fixture(scope="module")
def surveys():
    # the default demand rate for 20 minutes, two 10-minute slots
    cfg = small_config("milan", n_vehicles=513, duration_s=1200.0)
    sumo = sumo_survey(cfg, [0], n_slots=2, workers=1)
    env, params = make(cfg)
    sched = env.schedule_from_numpy(make_schedule(cfg, seed=0, penetration=0.0))
    return cfg, sumo, jax_survey(env, params, [sched], [0], n_slots=2)


@pytest.mark.sumo
def test_jax_survey_matches_sumo(surveys) -> None:
    _, sumo, jax = surveys
    assert sumo.queue_mean_veh.shape == (2, 4) == jax.queue_mean_veh.shape
    np.testing.assert_allclose(jax.upstream_veh_h, sumo.upstream_veh_h)
    assert np.abs(jax.downstream_veh_h - sumo.downstream_veh_h).max() <= 12.0
    assert sumo.queue_mean_veh.mean() > 0.1  # there are queues to fit
    rel = abs(jax.queue_mean_veh.mean() - sumo.queue_mean_veh.mean())
    assert rel <= 0.1 * sumo.queue_mean_veh.mean()
    assert np.abs(jax.queue_max_veh - sumo.queue_max_veh).max() <= 2.0


@pytest.mark.sumo
def test_survey_loss_is_zero_on_the_targets_and_grows_with_the_error(surveys) -> None:
    _, sumo, jax = surveys
    assert survey_loss(sumo, sumo) == 0.0
    doubled = dataclasses.replace(sumo, queue_mean_veh=2 * sumo.queue_mean_veh)
    assert 0.0 < survey_loss(jax, sumo) < survey_loss(doubled, sumo)


@pytest.mark.sumo
def test_survey_file_round_trip(surveys, tmp_path: Path) -> None:
    cfg, sumo, _ = surveys
    path = sumo.save(tmp_path / "t.json")
    back = load_survey(path)
    assert back.legs == tuple(leg.name for leg in cfg.network.legs)
    assert back.seeds == (0,) and back.source == "sumo"
    assert back.drivers["accel"] == pytest.approx(cfg.drivers.hv.accel)
    for name in MEASURES:
        np.testing.assert_allclose(getattr(back, name), getattr(sumo, name), atol=1e-6)


def test_bad_targets_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_survey(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match="not JSON"):
        load_survey(bad)
    bad.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ConfigError, match="jaxround measure"):
        load_survey(bad)
    good = {
        "format": "jaxround-survey/1", "legs": ["a", "b"], "slot_s": 600,
        **{name: [[1.0, 2.0]] for name in MEASURES},
    }  # fmt: skip
    good["queue_max_veh"] = [[1.0, 2.0, 3.0]]
    bad.write_text(json.dumps(good))
    with pytest.raises(ConfigError, match="queue_max_veh.*shape"):
        load_survey(bad)


def test_param_names_are_checked() -> None:
    assert parse_param_names("accel, tau") == ("accel", "tau")
    with pytest.raises(ConfigError, match="unknown"):
        parse_param_names("accel,speed")
    with pytest.raises(ConfigError, match="twice"):
        parse_param_names("tau,tau")


@pytest.mark.sumo
def test_measure_cli_writes_targets_with_the_drivers_given(tmp_path: Path) -> None:
    cfg_file = tmp_path / "small.yaml"
    cfg = small_config("milan", n_vehicles=60, duration_s=600.0)
    cfg_file.write_text(yaml.safe_dump(json.loads(json.dumps(cfg.to_dict()))))
    out = tmp_path / "targets.json"
    args = ["measure", "--config", str(cfg_file), "--out", str(out)]
    assert main([*args, "--set", "accel=2.2,tau=1.1", "--workers", "1"]) == 0
    survey = load_survey(out)
    assert survey.n_slots == 1
    assert survey.drivers["accel"] == pytest.approx(2.2)
    assert survey.drivers["tau"] == pytest.approx(1.1)
    before = out.read_bytes()
    assert main(args) == 2  # never overwritten without --force
    assert out.read_bytes() == before
    assert main([*args, "--slots", "2", "--force"]) == 2  # beyond the horizon
