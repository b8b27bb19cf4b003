"""The exit debt (`jaxround.analysis.exit_debt`) against SUMO's own vehicle.

One AV-like IDM vehicle (a 2.6 m/s^2, delta 4, HBEFA4/PC_petrol_Euro-4) is
inserted on a straight road with a 13.89 m/s limit at the speed it left the
network with; SUMO's CO2 and time over the next `AHEAD_M` metres, minus
those of a vehicle inserted at the limit, are the debt the table charges.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from jaxround.analysis.exit_debt import ACCEL, AHEAD_M, DELTA, debt_table
from jaxround.sumo_files.binaries import sumo_binary

pytestmark = pytest.mark.sumo

LIMIT_MPS = 13.89
STEP_S = 0.1


def _sumo_co2_and_time(folder: Path, depart_mps: float) -> tuple[float, float]:
    """SUMO's (CO2 g, time s) of one vehicle over `AHEAD_M` from `depart_mps`."""
    import libsumo

    routes = folder / f"r{depart_mps}.rou.xml"
    routes.write_text(
        f'<routes><vType id="av" carFollowModel="IDM" accel="{ACCEL}" '
        f'decel="4.2939" sigma="0" tau="1" delta="{DELTA}" minGap="2.5" length="5" '
        'maxSpeed="55.56" speedDev="0" emissionClass="HBEFA4/PC_petrol_Euro-4" '
        f'actionStepLength="{STEP_S}"/><route id="r" edges="e"/>'
        '<vehicle id="x" type="av" route="r" depart="0" departPos="100" '
        f'departSpeed="{depart_mps}"/></routes>'
    )
    libsumo.start([
        "sumo", "-n", str(folder / "n.net.xml"), "-r", str(routes),
        "--step-length", str(STEP_S), "--no-step-log", "--no-warnings",
    ])  # fmt: skip
    try:
        libsumo.simulationStep()
        start = libsumo.vehicle.getDistance("x")
        co2_mg = time_s = 0.0
        while libsumo.vehicle.getDistance("x") - start < AHEAD_M:
            libsumo.simulationStep()
            co2_mg += libsumo.vehicle.getCO2Emission("x") * STEP_S
            time_s += STEP_S
    finally:
        libsumo.close()
    return co2_mg / 1000.0, time_s


def test_exit_debt_matches_sumo(tmp_path: Path) -> None:
    (tmp_path / "n.nod.xml").write_text(
        '<nodes><node id="a" x="0" y="0"/><node id="b" x="1000" y="0"/></nodes>'
    )
    (tmp_path / "n.edg.xml").write_text(
        '<edges><edge id="e" from="a" to="b" numLanes="1" '
        f'speed="{LIMIT_MPS}"/></edges>'
    )
    subprocess.run(
        [sumo_binary("netconvert"), "-n", "n.nod.xml", "-e", "n.edg.xml",
         "-o", "n.net.xml"],
        cwd=tmp_path, check=True, capture_output=True,
    )  # fmt: skip
    at_limit = _sumo_co2_and_time(tmp_path, LIMIT_MPS)
    speeds, co2_g, time_s = debt_table(LIMIT_MPS)
    for leave_mps in (8.0, 10.0, 12.0):
        co2, t = _sumo_co2_and_time(tmp_path, leave_mps)
        sumo_debt_g, sumo_debt_s = co2 - at_limit[0], t - at_limit[1]
        table_g = float(np.interp(leave_mps, speeds, co2_g))
        table_s = float(np.interp(leave_mps, speeds, time_s))
        assert sumo_debt_g > 1.0, (leave_mps, sumo_debt_g)
        assert table_g == pytest.approx(sumo_debt_g, rel=0.03), leave_mps
        assert table_s == pytest.approx(sumo_debt_s, abs=2 * STEP_S), leave_mps
