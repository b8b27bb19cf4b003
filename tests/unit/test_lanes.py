"""Lane counts in the config: defaults that change nothing, refusals that
name the key, and the JAX side's refusal of two-lane roads (no SUMO run)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from jaxround.scenario.config import ConfigError, config_from_dict, load_config
from jaxround.sumo_files.netconvert import (
    connections_xml,
    network_fingerprint,
    plain_xml,
)
from tests.conftest import builtin_dict

#: What the single-lane scenarios hashed to before lanes could be counted:
#: (network_fingerprint, fingerprint, roads_and_drivers_fingerprint, the
#: plain XML netconvert reads). Cached networks, slot sizings and exported
#: policies are keyed by these, and netconvert's .net.xml by the plain XML.
SINGLE_LANE_HASHES = {
    "milan": ("60c980426ae1ba99", "1983268704fe731b", "e42e8fbf529512c8",
              "273227def4d381d6"),
    "three_leg": ("342ac1287b0d1bd1", "582a6b06ffe2a2ac", "0fd9aa7ff83d4c4e",
                  "8c0b385c19814666"),
    "six_leg": ("6db91a99d4521f39", "d8c4e8bbe0211ed5", "14f993d9961fc054",
                "640f135d9af8c042"),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(SINGLE_LANE_HASHES))
def test_single_lane_scenarios_are_unchanged(name: str) -> None:
    cfg = load_config(name)
    assert cfg.network.single_lane and cfg.network.ring_lanes == 1
    assert all(leg.entry_lanes == leg.exit_lanes == 1 for leg in cfg.network.legs)
    nodes, edges = plain_xml(cfg.network)
    plain = hashlib.sha256((nodes + edges).encode()).hexdigest()[:16]
    hashes = (
        network_fingerprint(cfg.network),
        cfg.fingerprint(),
        cfg.roads_and_drivers_fingerprint(),
        plain,
    )
    assert hashes == SINGLE_LANE_HASHES[name]
    assert connections_xml(cfg.network) is None  # netconvert's own joins
    assert "lanes" not in str(cfg.to_dict()["network"])  # default counts left out


def test_two_lane_scenario_loads_and_round_trips() -> None:
    cfg = load_config("two_lane")
    net = cfg.network
    assert net.ring_lanes == 2 and not net.single_lane
    assert all(leg.entry_lanes == 2 for leg in net.legs)
    assert config_from_dict(cfg.to_dict()) == cfg
    _, edges = plain_xml(net)
    assert edges.count('numLanes="2"') == len(net.legs) * 2  # ring edges, entries
    assert cfg.fingerprint() != load_config("milan").fingerprint()
    # the inscribed circle: NCHRP 672's 46-67 m for two-lane roundabouts
    assert net.inscribed_diameter_m == pytest.approx(50.0)  # 46-67 m


def test_two_lane_exits_join_lane_to_lane() -> None:
    d = builtin_dict("two_lane")
    for leg in d["network"]["legs"]:
        leg["exit_lanes"] = 2
    text = connections_xml(config_from_dict(d).network)
    assert text is not None
    # every ring lane on to the next ring edge and out at its own exit lane
    assert text.count("<connection ") == 4 * 2 * 2
    assert '<connection from="ring_3" to="out_0" fromLane="1" toLane="1"/>' in text
    assert '<connection from="ring_0" to="ring_1" fromLane="0" toLane="0"/>' in text


@pytest.mark.parametrize(
    ("base", "edit", "message"),
    [
        (
            "two_lane",
            lambda d: d["network"].update(ring_lanes=3),
            r"network\.ring_lanes: 3 lanes, expected 1 or 2",
        ),
        (
            "two_lane",
            lambda d: d["network"]["legs"][1].update(entry_lanes=0),
            r"network\.legs\[1\]\.entry_lanes: 0 lanes, expected 1 or 2",
        ),
        (
            "two_lane",
            lambda d: d["network"]["legs"][2].update(exit_lanes=3),
            r"network\.legs\[2\]\.exit_lanes: 3 lanes",
        ),
        (
            "milan",
            lambda d: d["network"]["legs"][0].update(entry_lanes=2),
            r"network\.legs\[0\]\.entry_lanes: 2 lanes on a one-lane ring "
            r"\(network\.ring_lanes: 1\)",
        ),
        (
            "milan",
            lambda d: d["network"]["legs"][3].update(exit_lanes=2),
            r"network\.legs\[3\]\.exit_lanes: 2 lanes on a one-lane ring",
        ),
        (
            "milan",
            lambda d: d["network"].update(ring_lanes=True),
            r"network\.ring_lanes: expected an integer",
        ),
        (
            "milan",
            lambda d: d["network"].update(lanes=2),
            r"network: unknown key 'lanes' \(allowed: .*ring_lanes\)",
        ),
        (
            "milan",
            lambda d: d["network"]["legs"][0].update(entry_lane=2),
            r"network\.legs\[0\]: unknown key 'entry_lane'",
        ),
        (
            "milan",  # two lanes on Milan's 12 m ring: no ring left between legs
            lambda d: d["network"].update(ring_lanes=2),
            r"network\.ring_radius_m: 12\.0 m leaves only 18\.8 m of ring between "
            r"two legs; need at least 24 m where a road has two lanes",
        ),
    ],
)
def test_lane_counts_are_refused_by_key(base: str, edit, message: str) -> None:
    d = builtin_dict(base)
    edit(d)
    with pytest.raises(ConfigError, match=message):
        config_from_dict(d)


def test_jax_refuses_two_lane_exits_before_netconvert_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The JAX step drives two-lane rings and entries, not two-lane exits
    (the inner lane's exit has an internal junction): `make` and parity
    refuse one, naming its key, before a network is built."""
    from jaxround.apps.parity import parity_report
    from jaxround.envs.roundabout import make

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    d = builtin_dict("two_lane")
    d["network"]["legs"][1]["exit_lanes"] = 2
    cfg = config_from_dict(d)
    message = r"network\.legs\[1\]\.exit_lanes: 2: two-lane exits run in SUMO only"
    with pytest.raises(ConfigError, match=message):
        make(cfg)
    with pytest.raises(ConfigError, match=message):
        parity_report(cfg, seeds=[0])
    assert not any(tmp_path.iterdir())  # no network was built
