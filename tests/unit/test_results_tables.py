"""The main job's summary tables and front figure from a hand-made
results.json, and the README's block of them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from jaxround.analysis.front_plot import plot_main_front
from jaxround.analysis.plots import plot_sweep
from jaxround.analysis.results_tables import (
    beside_rows,
    paired_rows,
    readme_markdown,
    write_results_tables,
)
from jaxround.apps.readme_tables import BEGIN, END, main, readme_block, with_block


def metrics(time_s: float, co2_g: float, hv_s: float | None = None) -> dict:
    def cls(n: int, t: float | None) -> dict[str, Any]:
        return {"n_vehicles": n, "mean_crossing_time_s": t, "co2_g_per_veh": co2_g,
                "fuel_g_per_veh": co2_g / 3, "consumption_score": 0.1,
                "emission_score": 0.1, "n_arrived": n}  # fmt: skip

    return {"all": cls(10, time_s), "hv": cls(5, hv_s), "av": cls(5, time_s)}


def pair(diff: float, base: float, ci: list[float] | None) -> dict[str, Any]:
    return {"diff": diff, "rel_diff": diff / base, "baseline": base, "ci95_seeds": ci}


def result(with_constant: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {"scenario": "milan", "seeds": [0, 1]}
    drivers = {"": 0.0, "_uncontrolled": 4.0}
    if with_constant:
        drivers["_best_constant"] = 0.5
    for sim in ("sumo", "jax"):
        for suffix, extra in drivers.items():
            out[sim + suffix] = {
                label: metrics(20.0 - p / 10 + extra, 50.0 - p / 10, 21.0)
                for label, p in (("0", 0), ("50", 50), ("100", 100))
            }
    every = {"all": {"crossing_time_s": pair(-4.0, 20.0, [-4.4, -3.6]),
                     "co2_g": pair(-5.0, 50.0, None)}}  # fmt: skip
    out["comparison"] = {"sumo": {"100": every}, "jax": {"100": every},
                         "sumo_to_jax_gain": {"100": 1.0}}  # fmt: skip
    if with_constant:
        out["comparison_best_constant"] = {
            "policy_vs_best_constant": {"sumo": {"100": every}, "jax": {}},
            "best_constant_vs_uncontrolled": {"sumo": {"100": every}},
        }
        out["best_constant"] = {
            "setting": {"tau": 0.5, "cruise_mps": None}, "source": "f.json",
            "objective": {"description": "1 per second"},
            "front": {"penetration": 1.0, "points": [
                {"time_s": 14.0, "co2_g": 41.0}, {"time_s": 15.0, "co2_g": 35.0}]},
        }  # fmt: skip
    return out


def test_rows_of_every_driver_and_pair() -> None:
    rows = beside_rows(result())
    assert [r[0] for r in rows] == [
        "SUMO, policy", "SUMO, best constant", "SUMO, uncontrolled AVs",
        "JAX, policy", "JAX, best constant", "JAX, uncontrolled AVs",
    ]  # fmt: skip
    assert rows[0][1:] == ["20.00 s / 50.0 g", "15.00 s / 45.0 g",
                           "10.00 s / 40.0 g", "21.00 s"]  # fmt: skip
    paired = paired_rows(result())
    assert paired[0] == ["SUMO, policy - uncontrolled AVs", "100",
                         "-4.00 s (-20.0%)", "[-22.0, -18.0]%",
                         "-5.00 g (-10.0%)", "-"]  # fmt: skip
    assert [r[0] for r in paired] == [
        "SUMO, policy - uncontrolled AVs", "SUMO, policy - best constant",
        "SUMO, best constant - uncontrolled AVs", "JAX, policy - uncontrolled AVs",
    ]  # fmt: skip
    # without a best constant its rows are left out
    plain = result(with_constant=False)
    assert len(beside_rows(plain)) == 4 and len(paired_rows(plain)) == 2
    assert "best constant (" not in readme_markdown(plain)


def test_files_and_figures(tmp_path: Path) -> None:
    r = result()
    write_results_tables(r, tmp_path)
    for name in ("beside.md", "beside.csv", "paired.md", "paired.csv"):
        assert (tmp_path / name).read_text().strip()
    assert (tmp_path / "readme_tables.md").read_text() == readme_markdown(r)
    plot_main_front(r, tmp_path / "front.png")
    assert (tmp_path / "front.png").stat().st_size > 10_000
    sweep = {p / 100: metrics(20.0, 50.0, 21.0) for p in (0, 50, 100)}
    plot_sweep({"sumo": sweep, "jax": sweep}, tmp_path / "f3.png", "t", "joint")
    assert (tmp_path / "f3.png").is_file()


def test_readme_block_is_replaced_and_checked(tmp_path: Path) -> None:
    text = f"# x\n\nbefore\n\n{BEGIN}\n\nold\n\n{END}\n\nafter\n"
    tables = readme_markdown(result())
    new = with_block(text, tables)
    assert readme_block(new) == tables
    assert new.startswith("# x\n\nbefore\n\n") and new.endswith(f"{END}\n\nafter\n")
    (tmp_path / "results.json").write_text(json.dumps(result()))
    (tmp_path / "README.md").write_text(text)
    args = [str(tmp_path / "results.json"), "--check", str(tmp_path / "README.md")]
    assert main(args) == 1
    assert main([args[0], "--write", args[2]]) == 0
    assert main(args) == 0
    with pytest.raises(ValueError, match="block"):
        readme_block("no markers")


@pytest.mark.parametrize(
    ("page", "results"),
    [("README.md", "docs/results/milan.json"),
     ("docs/two_lane.md", "docs/results/two_lane.json")],
)  # fmt: skip
def test_readme_tables_are_the_committed_results(page: str, results: str) -> None:
    # the main job's results.json of the default run (and of two_lane's),
    # kept in the repository
    root = Path(__file__).resolve().parents[2]
    tables = readme_markdown(json.loads((root / results).read_text()))
    assert readme_block((root / page).read_text()) == tables, (
        f"{page}'s results block is not {results}'s: run python -m "
        f"jaxround.apps.readme_tables {results} --write {page}"
    )


def test_conflicts_get_a_column_where_counted() -> None:
    r = result()
    assert "conflicts" not in readme_markdown(r)
    for sim in ("sumo", "jax"):
        for label, m in r[sim].items():
            m["all"]["conflicts_per_1000_veh"] = 10.0 * float(label)
    every = r["comparison"]["sumo"]["100"]["all"]  # shared by every pair here
    counted = {"diff": 33.8, "baseline": 11.7, "policy": 45.5}
    r["comparison"]["sumo"] = {
        "100": {"all": {**every, "conflicts_per_1000_veh": counted}}
    }
    assert beside_rows(r)[0][-1] == "0 / 500 / 1000"
    assert beside_rows(r)[1][-1] == "- / - / -"  # the best constant counted none
    assert paired_rows(r)[0][-1] == "+33.8 (11.7 to 45.5)"
    assert paired_rows(r)[1][-1] == "-"
    assert "conflicts per 1,000 vehicles" in readme_markdown(r)


def test_lane_changes_get_a_column_where_counted(tmp_path: Path) -> None:
    """Two-lane results: the side-by-side table's last column and the
    absolute table's three (all, AV, HV); none on one-lane roads."""
    from jaxround.analysis.report import write_tables

    r = result()
    assert "lane changes" not in readme_markdown(r)
    for label, m in r["sumo"].items():
        for cls, changes in (("all", 1.0), ("av", 1.25), ("hv", 0.75)):
            m[cls]["lane_changes_per_veh"] = changes + float(label) / 100
    assert beside_rows(r)[0][-1] == "1.00 / 1.50 / 2.00"
    assert beside_rows(r)[1][-1] == "- / - / -"  # the best constant counted none
    assert "lane changes per vehicle, 0 / 50 / 100% AVs" in readme_markdown(r)
    summary = {float(k) / 100: {**m, "collisions": 0} for k, m in r["sumo"].items()}
    write_tables(summary, tmp_path, "sumo_policy")
    lines = (tmp_path / "sumo_policy_absolute.csv").read_text().splitlines()
    assert lines[0].endswith(
        "lane changes per veh (all),lane changes per veh AV,lane changes per veh HV"
    )
    assert lines[2].endswith(",1.50,1.75,1.25")  # 50% AVs
    write_tables({p: r["jax"][k] for k, p in (("0", 0.0),)}, tmp_path, "jax")
    assert "lane changes" not in (tmp_path / "jax_absolute.csv").read_text()
