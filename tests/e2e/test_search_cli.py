"""`jaxround search` end to end on a tiny scenario (about 3 minutes on a loaded
2-core machine, most of it compiling the two programs)."""

from __future__ import annotations

import json

from jaxround.apps.cli.main import main
from jaxround.scenario.best_constant import load_best_constant
from tests.unit.test_search_cli import tiny_config


def test_search_writes_its_results_and_refuses_to_overwrite(tmp_path, capsys) -> None:
    config, out = tiny_config(tmp_path), tmp_path / "out"
    args = [
        "search", "--config", config, "--out", str(out), "--window-s", "60",
        "--search-seeds", "2", "--eval-seeds", "2", "--population", "2",
        "--generations", "1", "--max-vehicles", "16", "--penetration", "50",
    ]  # fmt: skip
    assert main(args) == 0
    result = json.loads((out / "search.json").read_text())
    assert (out / "search.png").stat().st_size > 0
    assert result["search_seeds"] == [200, 201] and result["eval_seeds"] == [100, 101]
    assert len(result["scored"]["objective"]) == 1 + 2  # the start, one generation
    ev = result["eval"]
    assert all(ev[k]["missing"] == 0 and ev[k]["overflow"] == 0 for k in ev)
    # the state-dependent search starts at the best constant: never worse there
    assert result["state_search_objective"] <= result["best_constant_search_objective"]
    printed = capsys.readouterr()
    assert "best constant" in printed.out
    # a tiny search may end worse than the vType; then it says so
    worse = result["constant_vs_vtype"]["rel_diff"] > 0
    assert ("the vType is the stronger baseline" in printed.err) == worse
    # and when the constant breaks the conflict limit on the evaluation seeds
    over = (
        result["eval"]["constant"]["conflicts_per_1000"]
        > result["conflict_limit_per_1000"]
    )
    assert ("above the limit" in printed.err) == over
    # a search at 50% AVs names the built-in file it would make
    assert "_p50.json and pass --best-constant " in printed.out
    # the best constant as the main job reads it, with the command that found it
    best = load_best_constant(out / "best_constant.json")
    assert best.setting == result["best_constant"] and best.front["points"]
    assert best.command.startswith("jaxround search --out DIR --config ")
    assert "--window-s 60 " in best.command and "--penetration 50 " in best.command
    assert main(args) == 2  # the results exist: refused before any work
    assert "already holds search.json" in capsys.readouterr().err
