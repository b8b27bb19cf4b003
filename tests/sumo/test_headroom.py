"""The headroom study's variants, summary table and figure (no simulation)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jaxround.analysis.compare import paired_difference
from jaxround.analysis.headroom_plot import plot, table
from jaxround.apps import headroom
from jaxround.scenario.records import VehicleRecords
from jaxround.scenario.schedule import make_schedule
from tests.conftest import small_config


def test_variants_start_with_the_vtype_and_are_unique() -> None:
    rows = headroom.variants()
    labels = [v.label for v in rows]
    assert labels[0] == "vtype" and rows[0].av == () and rows[0].controller is None
    assert len(set(labels)) == len(labels)
    assert "eco:0.3" in labels and "envelope+cruise:8" in labels


def test_speed_factor_variant_reaches_only_the_avs() -> None:
    cfg = small_config("milan", n_vehicles=80, duration_s=120.0)
    variant = headroom.Variant("speed_factor=1.1", (("speed_factor", 1.1),))
    vcfg = headroom.variant_config(cfg, variant)
    base = make_schedule(cfg, seed=100, penetration=0.5)
    (sched,) = [
        s for s in headroom.schedules(cfg, [100], variant) if s.n_av == base.n_av
    ]
    hv_dev, av_dev = vcfg.drivers.hv.speed_dev, vcfg.drivers.av.speed_dev
    factors = sched.class_speed_factors(hv_dev, av_dev)
    np.testing.assert_allclose(factors[sched.is_av], 1.1)
    original = base.class_speed_factors(hv_dev, cfg.drivers.av.speed_dev)
    np.testing.assert_array_equal(factors[~sched.is_av], original[~base.is_av])


def test_vtype_variant_changes_the_av_driver_only() -> None:
    cfg = small_config("milan")
    variant = headroom.Variant("envelope", headroom.ENVELOPE)
    vcfg = headroom.variant_config(cfg, variant)
    assert vcfg.drivers.av.tau == 0.6 and vcfg.drivers.av.impatience == 0.5
    assert vcfg.drivers.hv == cfg.drivers.hv
    with pytest.raises(ValueError, match="impatience"):
        headroom.variant_config(cfg, headroom.Variant("x", (("impatience", 2.0),)))


def records(crossing: np.ndarray, co2: np.ndarray) -> VehicleRecords:
    n = crossing.size
    return VehicleRecords(
        is_av=np.arange(n) % 2 == 0,
        origin=np.zeros(n, int),
        scheduled_depart_s=np.zeros(n),
        depart_s=np.zeros(n),
        arrival_s=crossing,
        co2_g=co2,
        fuel_g=co2 / 3,
        queue_mean_veh=np.zeros(4),
        queue_max_veh=np.zeros(4),
    )


def test_table_and_figure(tmp_path: Path) -> None:
    """Entries in `summarise`'s form: the table gives the paired difference
    in % of the vType, the figure is written."""
    rng = np.random.default_rng(0)
    base = [records(20 + rng.random(10), 50 + rng.random(10)) for _ in range(3)]

    def scaled(time_factor: float, co2_factor: float) -> list[VehicleRecords]:
        return [records(r.arrival_s * time_factor, r.co2_g * co2_factor) for r in base]

    runs = {"vtype": base}
    for field, values in headroom.SWEEP.items():
        for i, v in enumerate(values):
            runs[f"{field}={v:g}"] = scaled(1 + 0.01 * i, 1 - 0.01 * i)
    runs["envelope"] = scaled(0.9, 0.9)
    runs["eco:0.3"] = scaled(1.02, 1.0)
    entries = []
    for p in headroom.PENETRATIONS:
        for label, recs in runs.items():
            diff = paired_difference(recs, base)
            entries.append({
                "variant": label, "penetration": p, "sumo": diff, "jax": diff,
                "controller": "eco:0.3" if label == "eco:0.3" else None,
                "sumo_collisions": 0, "sumo_emergency_brakings": 0,
            })  # fmt: skip
    text = table(entries)
    assert "| 100% | envelope | " in text and "-10.0" in text
    path = tmp_path / "headroom.png"
    base_values = {f: 1.0 for f in headroom.SWEEP}
    plot(entries, headroom.SWEEP, base_values, path)
    assert path.stat().st_size > 10_000


def test_evaluation_seeds_only(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        headroom.main(["--out", str(tmp_path), "--seeds", "3"])
