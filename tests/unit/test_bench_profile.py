"""`jaxround bench --profile`: the step's time read back phase by phase."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from jaxround.apps.bench.profile import (
    OTHER,
    PHASES,
    format_profile,
    operation_phases,
    phase_of,
    profile_step,
)
from jaxround.apps.cli.main import main
from tests.conftest import small_config

KNOWN = {name for name, _ in PHASES} | {OTHER}


def test_phase_of_takes_the_innermost_phase_in_the_path() -> None:
    assert phase_of("jit(f)/vmap(look_ahead)/jit(_where)/select_n") == "look_ahead"
    assert phase_of("jit(f)/vmap(insertion)/vmap(queues)/add") == "queues"
    assert phase_of("jit(f)/while/body/look_ahead_extra/add") == OTHER
    assert phase_of("") == OTHER


def test_operation_phases_reads_the_named_scopes_of_a_compiled_program() -> None:
    def f(x: jax.Array) -> jax.Array:
        with jax.named_scope("look_ahead"):
            y = jnp.sin(x) * 2.0
        with jax.named_scope("final_speed"):
            return jnp.sum(jnp.cos(y) + 1.0)

    text = jax.jit(jax.vmap(f)).lower(jnp.ones((4, 8))).compile().as_text()
    phases = {phase for phase, _ in operation_phases(text).values()}
    assert {"look_ahead", "final_speed"} <= phases
    assert phases <= KNOWN


@pytest.fixture(scope="module")
def profile() -> dict:
    cfg = small_config(n_vehicles=150, duration_s=600.0)
    return profile_step(cfg, batch=2, sim_seconds=5.0, max_vehicles=16)


def test_the_step_time_is_spread_over_its_phases(profile: dict) -> None:
    assert profile["batch"] == 2 and profile["max_vehicles"] == 16
    assert profile["steps"] == 10 and profile["mean_vehicles"] > 0
    assert profile["wall_us_per_roundabout_step"] > 0
    names = [row["phase"] for row in profile["phases"]]
    assert set(names) <= KNOWN and len(names) == len(set(names))
    order = [name for name, _ in PHASES] + [OTHER]
    assert names == sorted(names, key=order.index)  # in the step's order
    us = {row["phase"]: row["us"] for row in profile["phases"]}
    for phase in ("neighbour_tables", "own_leader", "look_ahead", "insertion"):
        assert us.get(phase, 0.0) > 0, phase
    assert sum(us.values()) == pytest.approx(profile["cpu_us_per_roundabout_step"])
    assert sum(row["share"] for row in profile["phases"]) == pytest.approx(1.0)
    top = profile["top_operations"]
    assert 0 < len(top) <= 10 and all(op["phase"] in KNOWN for op in top)
    assert [op["us"] for op in top] == sorted((op["us"] for op in top), reverse=True)


def test_the_profile_prints_as_a_table_with_bars(profile: dict) -> None:
    text = format_profile(profile)
    assert "| look_ahead |" in text and "#" in text
    assert f"M = {profile['max_vehicles']} slots" in text


def test_bad_arguments_fail_before_work(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="batch"):
        profile_step(small_config(), batch=0)
    with pytest.raises(ValueError, match="sim_seconds"):
        profile_step(small_config(), sim_seconds=0.0)
    assert main(["bench", "--batch", "4"]) == 2
    assert "--batch: only with --profile" in capsys.readouterr().err


def test_every_named_scope_of_the_step_is_a_phase() -> None:
    # a scope the profile does not know would be counted as "other"
    root = Path(__file__).resolve().parents[2] / "jaxround"
    sources = [root / "core" / "dynamics.py", root / "envs" / "roundabout.py"]
    scopes = {
        name
        for path in sources
        for name in re.findall(r'named_scope\("(\w+)"\)', path.read_text())
    }
    assert scopes == {name for name, _ in PHASES}
