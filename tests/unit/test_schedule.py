"""Departure schedules: exact counts, seeding, and the arrays both simulators read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jaxround.scenario.config import load_config
from jaxround.scenario.schedule import Schedule, make_schedule, n_av_at


@pytest.mark.parametrize(
    ("p", "n_av"),
    [(0.0, 0), (0.1, 154), (0.2, 308), (0.5, 770), (0.9, 1386), (1.0, 1540)],
)
def test_exact_av_counts_as_in_the_paper(p: float, n_av: int) -> None:
    s = make_schedule(load_config(), seed=3, penetration=p)
    assert s.n_vehicles == 1540
    assert int(s.is_av.sum()) == n_av == s.n_av
    assert int((~s.is_av).sum()) == 1540 - n_av


def test_rounding_of_av_count() -> None:
    assert n_av_at(0.25, 10) == 3  # 2.5 rounds up
    assert n_av_at(0.333, 1000) == 333
    assert n_av_at(1.0, 7) == 7


def test_same_seed_same_schedule_other_seed_other() -> None:
    cfg = load_config()
    a, b, c = (
        make_schedule(cfg, seed=1),
        make_schedule(cfg, seed=1),
        make_schedule(cfg, seed=2),
    )
    for name in ("depart_s", "origin", "destination", "speed_factor", "av_rank"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.depart_s, c.depart_s)


def test_penetration_only_changes_classes_and_nests() -> None:
    cfg = load_config()
    low = make_schedule(cfg, seed=0, penetration=0.1)
    high = make_schedule(cfg, seed=0, penetration=0.3)
    np.testing.assert_array_equal(low.depart_s, high.depart_s)
    np.testing.assert_array_equal(low.origin, high.origin)
    assert np.all(high.is_av[low.is_av])  # AVs at 10% are AVs at 30%


def test_schedule_values_are_well_formed() -> None:
    cfg = load_config()
    s = make_schedule(cfg, seed=5)
    dt = cfg.simulation.dt_s
    assert np.all(np.diff(s.depart_s) >= 0)
    assert s.depart_s.min() >= 0 and s.depart_s.max() < cfg.demand.duration_s
    np.testing.assert_allclose(s.depart_s / dt, np.round(s.depart_s / dt))
    assert np.all(s.origin != s.destination)
    assert np.all((s.speed_factor >= 0.2) & (s.speed_factor <= 2.0))
    assert abs(s.speed_factor.mean() - 1.0) < 0.02
    assert abs(s.speed_factor.std() - cfg.drivers.hv.speed_dev) < 0.02
    shares = np.bincount(s.origin, minlength=cfg.n_legs) / s.n_vehicles
    np.testing.assert_allclose(shares, cfg.demand.origin_share, atol=0.05)
    np.testing.assert_array_equal(np.sort(s.av_rank), np.arange(s.n_vehicles))


def test_save_load_round_trip_and_damaged_file(tmp_path: Path) -> None:
    s = make_schedule(load_config(), seed=0, penetration=0.4)
    path = tmp_path / "s.npz"
    s.save(path)
    back = Schedule.load(path)
    assert back.penetration == 0.4
    np.testing.assert_array_equal(back.is_av, s.is_av)
    np.testing.assert_array_equal(back.speed_factor, s.speed_factor)
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match="cannot read schedule"):
        Schedule.load(path)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="penetration"):
        make_schedule(load_config(), penetration=1.5)
    with pytest.raises(ValueError, match="seed"):
        make_schedule(load_config(), seed=-1)
