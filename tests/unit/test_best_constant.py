"""The best constant's versioned file: what it holds, how it is read and
applied, and that it is what `jaxround search` wrote."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from jaxround.apps.cli.search import search_command
from jaxround.apps.search_best_constant import best_constant_file
from jaxround.scenario.best_constant import (
    BestConstant,
    builtin_path,
    load_best_constant,
)
from jaxround.scenario.config import ConfigError, load_config

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(("name", "search", "percent"), [
    ("milan", "p100", 100), ("milan_p50", "p50", 50),
])  # fmt: skip
def test_milan_files_are_what_their_search_wrote(
    name: str, search: str, percent: int
) -> None:
    # docs/safety/search/<search>.json is the search's result (the best safe
    # constant: the time-gap floor and the conflict limit); the file is the
    # search's own best_constant.json of it, with the command that ran it
    result = json.loads((ROOT / f"docs/safety/search/{search}.json").read_text())
    saved = json.loads(builtin_path(name).read_text())
    assert best_constant_file(result, saved["command"]) == saved
    assert saved["found"]["penetration"] == percent / 100
    assert saved["command"].startswith(
        f"jaxround search --out DIR --config milan --penetration {percent} "
        "--window-s 600 "
    )
    assert saved["command"].endswith("--conflict-limit vtype")
    assert saved["setting"]["tau"] >= load_config("milan").safety.min_av_tau_s


def test_the_two_lane_file_at_50_percent_is_what_its_search_wrote() -> None:
    # docs/results/two_lane_search_p50.json is the search's result
    result = json.loads((ROOT / "docs/results/two_lane_search_p50.json").read_text())
    saved = json.loads(builtin_path("two_lane_p50").read_text())
    assert best_constant_file(result, saved["command"]) == saved
    assert saved["found"]["penetration"] == 0.5
    assert saved["command"].startswith(
        "jaxround search --out DIR --config two_lane --penetration 50 "
    )
    assert load_best_constant("two_lane_p50").setting == result["best_constant"]


def test_the_command_spells_out_every_option() -> None:
    args = argparse.Namespace(
        config=None, penetration=0.5, window_s=1800.0, demand_scale=1.5,
        search_seeds=8, eval_seeds=20, population=24, generations=8,
        state_generations=None, time_weight=1.0, co2_weight=0.5,
        charge_exit=False, conflict_weight=0.0, conflict_limit=None,
        origin_share=(0.55, 0.05, 0.35, 0.05), max_vehicles=None,
    )  # fmt: skip
    assert search_command(args) == (
        "jaxround search --out DIR --config milan --penetration 50 --window-s 1800 "
        "--demand-scale 1.5 --search-seeds 8 --eval-seeds 20 --population 24 "
        "--generations 8 --state-generations 8 --time-weight 1 --co2-weight 0.5 "
        "--no-charge-exit --conflict-weight 0 --conflict-limit none "
        "--origin-share 0.55,0.05,0.35,0.05"
    )


def test_loaded_setting_goes_into_the_av_vtype_only() -> None:
    constant = load_best_constant("milan")
    assert constant.source == "configs/best_constant/milan.json"
    cfg = load_config("milan")
    tuned = constant.config_for(cfg)
    for name, value in constant.vtype.items():
        assert getattr(tuned.drivers.av, name) == pytest.approx(value)
    assert tuned.drivers.hv == cfg.drivers.hv
    assert constant.front["points"] and constant.objective["description"]


def test_any_vtype_number_and_a_cruise_speed() -> None:
    constant = BestConstant(
        scenario="milan", setting={"min_gap": 2.0, "cruise_mps": 9.5},
        objective={"description": "x"}, command="jaxround search --out DIR",
    )  # fmt: skip
    assert constant.vtype == {"min_gap": 2.0}
    assert constant.controller_spec == "cruise:9.5"
    # min_gap is one both classes share in JAX: refused for the AVs alone
    with pytest.raises(ConfigError):
        constant.config_for(load_config("milan"))


def test_bad_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown setting"):
        BestConstant("milan", {"courage": 1.0}, {}, "")
    with pytest.raises(ConfigError, match="no such file"):
        load_best_constant(tmp_path / "missing.json")
    path = tmp_path / "b.json"
    path.write_text(json.dumps({"scenario": "milan", "setting": {"tau": 0.7}}))
    with pytest.raises(ConfigError, match="missing"):
        load_best_constant(path)
