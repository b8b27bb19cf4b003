"""`python -m jaxround.apps.bench.changer`: bad arguments are refused before
SUMO or JAX starts, and the rows read as a table (the changers' agreement
itself: tests/sumo/test_ring_rounds.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from jaxround.apps.bench import changer
from tests.conftest import refused


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--duration", "100", "--skip", "120"], "--skip 120"),
        (["--skip", "-1"], "--skip -1"),
        (["--batch", "0"], "--batch [0]"),
    ],
)
def test_bad_arguments_are_refused_before_work(
    argv: list[str], named: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert named in refused(changer.main, argv, capsys)


def test_an_existing_json_is_not_overwritten(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kept = tmp_path / "rows.json"
    kept.write_text("{}")
    with pytest.raises(SystemExit):
        changer.main(["--json", str(kept)])
    assert "exists" in capsys.readouterr().err
    assert kept.read_text() == "{}"


def test_rows_read_as_a_table_with_the_ratio_to_milan() -> None:
    row = {
        "batch": 16, "slots": 48, "milan_slots": 32, "mean_vehicles": 24.0,
        "milan_vehicles": 9.0, "us_per_vehicle_step_sequential": 30.0,
        "us_per_vehicle_step_rounds": 6.0, "rounds_mean": 1.9, "rounds_max": 3,
        "milan_us_per_vehicle_step": 4.0,
    }  # fmt: skip
    text = changer.report([row], "a CPU")
    lines = text.splitlines()
    assert lines[0] == "On a CPU, per vehicle-step:"
    cells = [cell.strip() for cell in lines[-1].split("|")[1:-1]]
    assert cells == ["16", "48 / 32", "24.0 / 9.0", "30", "6", "1.90 (3)", "4", "1.50"]
