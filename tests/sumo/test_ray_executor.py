"""``--executor ray``: SUMO runs as tasks on a local Ray cluster give the numbers
of the local process pool (`sumo_export.executors`)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

ray = pytest.importorskip("ray")

from jaxround.apps.cli.main import main  # noqa: E402
from sumo_export import executors  # noqa: E402
from tests.conftest import builtin_dict  # noqa: E402

pytestmark = pytest.mark.sumo

#: Numbers that measure the machine, not the traffic.
TIMINGS = ("wall_s", "controller")
#: Eq. 5's scores: evaluate takes their scale over its JAX runs too
SCORES = ("consumption_score", "emission_score", "score_scale")


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    """A local Ray cluster of two CPUs, for this module only."""
    ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1")
    yield
    ray.shutdown()
    executors.use_executor("local")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = builtin_dict("milan")
    d["demand"]["n_vehicles"], d["demand"]["duration_s"] = 40, 100.0
    path = tmp_path_factory.mktemp("scenario") / "small.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def traffic_numbers(x: Any) -> Any:
    """`x` without its timings and scores."""
    if isinstance(x, dict):
        return {
            k: traffic_numbers(v) for k, v in x.items() if k not in TIMINGS + SCORES
        }
    if isinstance(x, list):
        return [traffic_numbers(v) for v in x]
    return x


def test_an_unknown_executor_is_named_before_any_work() -> None:
    with pytest.raises(ValueError, match="'dask'"):
        executors.use_executor("dask")
    with pytest.raises(SystemExit):
        main(["sumo", "--executor", "dask"])


def test_jaxround_sumo_on_ray_gives_the_local_pools_numbers(
    local_ray: None, scenario: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["sumo", "--config", str(scenario), "--seeds", "2", "--json",
            "--no-progress", "--workers", "2"]  # fmt: skip
    assert main(argv) == 0
    local = json.loads(capsys.readouterr().out)
    assert executors.current_executor() == "local"
    assert main([*argv, "--executor", "ray"]) == 0
    assert executors.current_executor() == "ray"
    on_ray = json.loads(capsys.readouterr().out)
    assert traffic_numbers(on_ray) == traffic_numbers(local)
    assert len(local["per_seed"]) == 2 and local["mean"]["all"]["n_arrived"] == 40
