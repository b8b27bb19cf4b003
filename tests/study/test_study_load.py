"""``jaxround study load``: scripted riders against a real server, figures out.

Only that the command runs and its figures hang together; the delay figures
themselves are measured on purpose (docs/study.md), never asserted.
"""

from __future__ import annotations

import json

import pytest

from jaxround.apps.cli.main import main

pytestmark = pytest.mark.sumo


def test_two_scripted_riders_finish_and_the_delays_are_reported(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["study", "load", "--participants", "2", "--seconds", "3",
            "--warmup-s", "10", "--json"]  # fmt: skip
    assert main(argv) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["participants"] == 2
    rides = figures["rides"]
    assert [r["status"] for r in rides] == ["time_limit"] * 2, rides  # with errors
    assert figures["rides_dropped"] == 0
    assert figures["steps"] == 2 * 30  # every step's frame reached its rider
    assert all(r["frames"] == 30 for r in figures["rides"])
    delay = figures["delay_ms"]
    assert 0 < delay["median"] <= delay["p99"] <= delay["max"]
    assert figures["policy_step_ms"]["median"] > 0  # the policy drove AVs
    latency = figures["latency_ms"]
    assert latency["inputs"] >= 2  # the riders' pedal changes, each timed
    parts = ("relay_in", "wait", "sumo", "frame", "relay_out", "websocket")
    assert sum(latency[p]["median"] for p in parts) > 0
    assert 0 < latency["total"]["median"] <= latency["total"]["p99"]


def test_load_refuses_counts_and_durations_out_of_bounds(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["study", "load", "--participants", "0"])
    assert "expected 1-32" in capsys.readouterr().err
    assert main(["study", "load", "--participants", "1", "--seconds", "900"]) == 2
    assert "seconds: 900.0, expected 1-600" in capsys.readouterr().err
