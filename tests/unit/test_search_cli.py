"""`jaxround search` refuses bad input before any work (the run itself:
`tests/e2e/test_search_cli.py`)."""

from __future__ import annotations

import yaml

from jaxround.apps.cli.main import main
from tests.conftest import builtin_dict


def tiny_config(tmp_path) -> str:
    d = builtin_dict("milan")
    d["name"] = "tiny"
    d["demand"]["n_vehicles"] = 20
    d["demand"]["duration_s"] = 60.0
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(d))
    return str(path)


def test_search_refuses_bad_input_before_work(tmp_path, capsys) -> None:
    config = tiny_config(tmp_path)
    base = ["search", "--config", config, "--out", str(tmp_path / "o")]
    assert main([*base, "--origin-share", "0.5,0.5"]) == 2
    assert "2 shares for 4 legs" in capsys.readouterr().err
    assert main([*base, "--time-weight", "0", "--co2-weight", "0"]) == 2
    assert not (tmp_path / "o").exists()
