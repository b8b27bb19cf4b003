"""The training progress bar says what an update measured, never "nan"."""

from __future__ import annotations

import math

from agents.run.progress_bar import ProgressBar


def shown(metrics: dict[str, float]) -> str:
    bar = ProgressBar(total=3, initial=0)
    try:
        bar(1, metrics)
        return bar.bar.postfix
    finally:
        bar.close()


def test_an_update_with_finished_avs_shows_their_means() -> None:
    text = shown(
        {
            "env_steps_per_s": 3221.4,
            "episode_return": -41.257,
            "av_crossing_time_s": 15.04,
        }
    )
    assert text == "3,221 env-steps/s, return -41.26, AV crossing 15.0 s"


def test_an_update_where_no_av_left_says_so() -> None:
    text = shown(
        {"env_steps_per_s": 2697.0, "episode_return": math.nan,
         "av_crossing_time_s": math.nan}
    )  # fmt: skip
    assert "nan" not in text
    assert text == "2,697 env-steps/s, no AV left the roundabouts in this update"
