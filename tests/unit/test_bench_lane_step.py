"""`python -m jaxround.apps.bench.lane_step` refuses bad input before any timing."""

import pytest

from jaxround.apps.bench import lane_step


def test_a_batch_below_one_is_refused(capsys):
    with pytest.raises(SystemExit):
        lane_step.main(["--batch", "16", "0", "--no-sumo"])
    assert "batch 0: expected a positive integer" in capsys.readouterr().err


def test_an_existing_results_file_is_not_overwritten(tmp_path, capsys):
    out = tmp_path / "bench.json"
    out.write_text("{}")
    with pytest.raises(SystemExit):
        lane_step.main(["--batch", "16", "--no-sumo", "--out", str(out)])
    assert "exists" in capsys.readouterr().err
    assert out.read_text() == "{}"


def test_a_negative_alternation_is_refused(capsys):
    with pytest.raises(SystemExit):
        lane_step.main(["--batch", "16", "--alternate", "-1"])
    assert "--alternate -1: expected N >= 1" in capsys.readouterr().err
