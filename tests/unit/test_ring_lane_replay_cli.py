"""`python -m jaxround.apps.ring_lane_replay`: bad arguments are refused
before SUMO or JAX starts."""

from __future__ import annotations

import pytest

from jaxround.apps import ring_lane_replay
from tests.conftest import refused


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--penetration", "1.5"], "--penetration 1.5"),
        (["--policy", "gap:x"], "gap:X"),
        (["--policy", "gap:-2"], "gap:X"),
        (["--policy", "sideways"], "'sideways'"),
        (["--duration", "0"], "--duration 0"),
    ],
)
def test_bad_arguments_are_refused_before_work(
    argv: list[str], named: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert named in refused(ring_lane_replay.main, argv, capsys)
