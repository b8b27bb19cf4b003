"""Paired differences of a policy against a baseline, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from jaxround.analysis.compare import mean_ci, paired_difference, t95
from jaxround.scenario.records import VehicleRecords


def records(
    crossing: list[float], co2: list[float], is_av: list[bool]
) -> VehicleRecords:
    n = len(crossing)
    return VehicleRecords(
        is_av=np.asarray(is_av),
        origin=np.zeros(n, np.int64),
        scheduled_depart_s=np.zeros(n),
        depart_s=np.zeros(n),
        arrival_s=np.asarray(crossing, np.float64),
        co2_g=np.asarray(co2, np.float64),
        fuel_g=np.asarray(co2, np.float64) / 3.0,
        queue_mean_veh=np.zeros(4),
        queue_max_veh=np.zeros(4),
    )


def test_mean_ci_by_hand() -> None:
    mean, low, high = mean_ci(np.array([1.0, 2.0, 3.0]))
    # mean 2, std 1, n 3: half width 4.303 / sqrt(3)
    assert mean == 2.0
    assert high - mean == pytest.approx(4.303 / np.sqrt(3.0))
    assert low == pytest.approx(2.0 - 4.303 / np.sqrt(3.0))
    assert mean_ci(np.array([1.0])) is None
    assert t95(1) == 12.706 and t95(500) == 1.960
    with pytest.raises(ValueError, match="degrees of freedom"):
        t95(0)


def test_paired_difference_by_hand() -> None:
    av = [True, True, False]
    pol = [records([9.0, 10.0, 20.0], [40.0, 50.0, 60.0], av),
           records([8.0, 12.0, np.nan], [30.0, 50.0, np.nan], av)]  # fmt: skip
    base = [records([10.0, 11.0, 20.0], [40.0, 50.0, 66.0], av),
            records([10.0, 12.0, 25.0], [40.0, 60.0, 70.0], av)]  # fmt: skip
    result = paired_difference(pol, base)
    t = result["crossing_time_s"]
    # seed 0: diffs -1, -1, 0 -> -2/3; seed 1 (vehicle 2 did not arrive): -2, 0 -> -1
    assert t["per_seed_diff"] == pytest.approx([-2 / 3, -1.0])
    assert t["diff"] == pytest.approx(-5 / 6)
    assert t["baseline"] == pytest.approx((41 / 3 + 11) / 2)
    assert t["n_vehicles"] == 5
    half = 12.706 * np.std([-2 / 3, -1.0], ddof=1) / np.sqrt(2)
    assert t["ci95_seeds"] == pytest.approx([-5 / 6 - half, -5 / 6 + half])
    lo, hi = t["ci95_vehicles"]
    assert lo < -0.8 < hi
    hv = paired_difference(pol, base, "hv")["co2_g"]
    assert hv["per_seed_diff"] == pytest.approx([-6.0])  # seed 1's HV never arrived
    assert hv["ci95_seeds"] is None


def test_paired_difference_refuses_unpaired_runs() -> None:
    a = records([1.0], [1.0], [True])
    with pytest.raises(ValueError, match="same number"):
        paired_difference([a], [a, a])
    with pytest.raises(ValueError, match="other vehicles"):
        paired_difference([a], [records([1.0], [1.0], [False])])


def test_parity_errors_schedule_by_schedule() -> None:
    # JAX 10% slower than SUMO on one schedule and 10% faster on the other:
    # the mean is 0 and the 95% interval t95(1) * sd / sqrt(2) wide each side
    from jaxround.apps.parity import seed_errors

    def metrics(crossing: float, co2: float | None) -> dict:
        return {"all": {"mean_crossing_time_s": crossing, "co2_g_per_veh": co2}}

    jax_runs = [metrics(44.0, 80.0), metrics(36.0, None)]
    sumo_runs = [metrics(40.0, 80.0), metrics(40.0, 70.0)]
    out = seed_errors(jax_runs, sumo_runs)
    crossing = out["mean_crossing_time_s"]
    assert crossing["per_seed"] == pytest.approx([0.1, -0.1])
    assert crossing["mean"] == pytest.approx(0.0, abs=1e-12)
    half = t95(1) * np.std([0.1, -0.1], ddof=1) / np.sqrt(2)
    assert crossing["ci95"] == pytest.approx([-half, half])
    # a run without a value is left out of the mean, and one value has no interval
    co2 = out["co2_g_per_veh"]
    assert co2["per_seed"] == [0.0, None]
    assert co2["mean"] == 0.0 and co2["ci95"] is None


def test_parity_text_gives_the_errors_by_schedule(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from jaxround.apps.cli.simulate import print_seed_errors

    report = {
        "seeds": [0, 1],
        "rel_err_by_seed": {
            "mean_crossing_time_s": {
                "per_seed": [0.1, -0.1], "mean": 0.0, "ci95": [-0.9, 0.9],
            },
            "co2_g_per_veh": {"per_seed": [0.0, None], "mean": 0.0, "ci95": None},
        },
    }  # fmt: skip
    print_seed_errors(report)
    out = capsys.readouterr().out
    assert "crossing time error by schedule (%): +10.0, -10.0; mean +0.00%" in out
    assert "over the 2 schedules [-90.00, +90.00]" in out
    assert "CO2" not in out  # one schedule's value: no interval to give
