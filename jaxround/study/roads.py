"""The roads of a ``.net.xml`` as plain data for the browser's 3D view.

The browser builds its road surface from the very lane shapes SUMO drives
on (``<lane shape=...>``, internal junction lanes included) and fills the
junction areas from their ``<junction shape=...>`` polygons, so the drawn
roads and the simulated ones are the same.
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from jaxround.scenario.config import ScenarioConfig
from jaxround.sumo_files.netconvert import build_network

#: SUMO's lane width when the network does not give one, m.
DEFAULT_LANE_WIDTH_M = 3.2


def parse_shape(text: str) -> list[list[float]]:
    """'x1,y1 x2,y2 ...' -> [[x1, y1], [x2, y2], ...]."""
    points = []
    for pair in text.split():
        x, y = pair.split(",")[:2]
        points.append([round(float(x), 3), round(float(y), 3)])
    return points


def road_geometry(net_file: Path) -> dict[str, Any]:
    """Lanes, junction areas and bounds of a network.

    Returns:
        ``{"lanes": [{"id", "shape": [[x, y], ...], "width", "internal"}],
        "junctions": [[[x, y], ...], ...], "bounds": [xmin, ymin, xmax, ymax]}``
        in SUMO's coordinates (m, x east, y north).
    """
    root = ET.parse(net_file).getroot()
    lanes = []
    for edge in root.iter("edge"):
        internal = edge.get("function") == "internal"
        for lane in edge.iter("lane"):
            lanes.append(
                {
                    "id": lane.get("id"),
                    "shape": parse_shape(lane.get("shape", "")),
                    "width": float(lane.get("width", DEFAULT_LANE_WIDTH_M)),
                    "internal": internal,
                }
            )
    junctions = [
        parse_shape(j.get("shape"))
        for j in root.iter("junction")
        if j.get("type") != "internal" and j.get("shape")
    ]
    xs = [p[0] for lane in lanes for p in lane["shape"]]
    ys = [p[1] for lane in lanes for p in lane["shape"]]
    return {
        "lanes": lanes,
        "junctions": junctions,
        "bounds": [min(xs), min(ys), max(xs), max(ys)],
    }


def scenario_roads(cfg: ScenarioConfig) -> dict[str, Any]:
    """`road_geometry` of the scenario's network, built with netconvert."""
    with tempfile.TemporaryDirectory(prefix="jaxround-roads-") as tmp:
        net = build_network(cfg.network, Path(tmp), cfg.name)
        return road_geometry(net)
