"""Config parsing: the built-in scenarios load; bad values name their field."""

from __future__ import annotations

from pathlib import Path

import pytest

from jaxround.scenario.config import (
    ConfigError,
    builtin_configs,
    config_from_dict,
    load_config,
)


def test_builtin_scenarios_load() -> None:
    assert {"milan", "three_leg", "six_leg"} <= set(builtin_configs())
    milan = load_config()
    assert milan.name == "milan"
    assert milan.n_legs == 4
    assert milan.demand.n_vehicles == 1540
    assert milan.demand.duration_s == 3600.0
    assert milan.simulation.dt_s == 0.5
    hv = milan.drivers.hv
    assert hv.car_follow_model == "IDM"
    table2 = dict(
        accel=1.7634,
        decel=4.2939,
        tau=1.3472,
        action_step_length=0.505,
        jm_timegap_minor=1.7792,
        impatience=0.1182,
        jm_crossing_gap=1.3545,
    )
    for name, value in table2.items():
        assert getattr(hv, name) == value, name
    shares = sorted(milan.demand.origin_share)
    assert shares[-1] == shares[-2] > shares[0]  # two heavier arterials
    assert load_config("three_leg").n_legs == 3
    assert load_config("six_leg").n_legs == 6


def test_load_from_file(tmp_path: Path, milan_dict: dict) -> None:
    import yaml

    path = tmp_path / "mine.yaml"
    milan_dict["name"] = "mine"
    path.write_text(yaml.safe_dump(milan_dict))
    assert load_config(path).name == "mine"
    assert load_config(str(path)).name == "mine"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda d: d["network"].update(ring_radiuss=3),
            r"network: unknown key 'ring_radiuss'",
        ),
        (lambda d: d.update(extra=1), r"config: unknown key 'extra'"),
        (
            lambda d: d["network"]["legs"][1].update(length_m=-5.0),
            r"network\.legs\[1\]\.length_m: -5\.0, expected > 0",
        ),
        (
            lambda d: d["simulation"].update(penetration=1.2),
            r"simulation\.penetration: 1\.2, expected a share in \[0, 1\]",
        ),
        (
            lambda d: d["simulation"].update(penetration=-0.1),
            r"simulation\.penetration",
        ),
        (
            lambda d: d["demand"]["od"][2].__setitem__(1, 0.5),
            r"demand\.od\[2\]: sums to 1\.3, expected 1",
        ),
        (
            lambda d: d["demand"].update(origin_share=[0.5, 0.5, 0.5, 0.5]),
            r"demand\.origin_share: sums to 2",
        ),
        (lambda d: d["demand"]["od"][0].__setitem__(0, 0.1), r"demand\.od\[0\]"),
        (
            lambda d: d["network"].update(legs=d["network"]["legs"][:2]),
            r"network\.legs: 2 legs, expected 3 to 6",
        ),
        (lambda d: d["drivers"]["hv"].pop("tau"), r"drivers\.hv\.tau: missing"),
        (
            lambda d: d["drivers"]["hv"].update(accel="fast"),
            r"drivers\.hv\.accel: expected a number, got 'fast'",
        ),
        (
            lambda d: d["drivers"]["av"].update(car_follow_model="Wiedemann"),
            r"drivers\.av\.car_follow_model",
        ),
        (
            lambda d: d["drivers"]["hv"].update(impatience=1.5),
            r"drivers\.hv\.impatience",
        ),
        (lambda d: d["demand"].update(n_vehicles=0), r"demand\.n_vehicles"),
        (
            lambda d: d["demand"].update(n_vehicles=10.5),
            r"demand\.n_vehicles: expected an integer",
        ),
        (lambda d: d["network"].update(ring_radius_m=2.0), r"network\.ring_radius_m"),
        (lambda d: d["network"]["legs"][3].update(name="east"), r"leg names repeat"),
    ],
)
def test_bad_values_name_the_field(milan_dict: dict, edit, message: str) -> None:
    edit(milan_dict)
    with pytest.raises(ConfigError, match=message):
        config_from_dict(milan_dict)


def test_unknown_builtin_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match="no scenario config file of that name, nor a built-in"
    ):
        load_config("atlantis")
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_overrides_are_validated() -> None:
    cfg = load_config()
    assert cfg.with_overrides(penetration=0.3).simulation.penetration == 0.3
    with pytest.raises(ConfigError, match="penetration"):
        cfg.with_overrides(penetration=3.0)
    with pytest.raises(ConfigError, match="unknown override"):
        cfg.with_overrides(speed=3.0)


def test_fingerprint_ignores_seed_but_not_network() -> None:
    cfg = load_config()
    assert (
        cfg.fingerprint() == cfg.with_overrides(seed=7, penetration=0.5).fingerprint()
    )
    assert cfg.fingerprint() != load_config("three_leg").fingerprint()
