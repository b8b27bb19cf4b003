"""Write a roundabout as SUMO plain XML and compile it with netconvert.

Nodes: ``c{i}`` where leg ``i`` meets the ring, ``o{i}`` the leg's far end.
The edges' ids are those of `jaxround.scenario.edges`. Each edge has the
lanes the config gives it (`jaxround.scenario.roads`); lane ``_0`` is the
rightmost, so on the ring (counter-clockwise) ``ring_i_0`` is the outer lane
and ``ring_i_1`` the inner one.

netconvert joins the lanes itself, and its joins are those of a two-lane
roundabout everywhere but at a two-lane exit (`connections_xml` says why and
writes that junction's joins).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import tempfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

from jaxround.scenario.config import NetworkConfig, ScenarioConfig
from jaxround.scenario.edges import in_edge, out_edge, ring_edge
from jaxround.sumo_files.binaries import sumo_binary


def _point(radius: float, angle_deg: float) -> tuple[float, float]:
    a = math.radians(angle_deg)
    return radius * math.cos(a), radius * math.sin(a)


def _fmt(p: tuple[float, float]) -> str:
    return f"{p[0]:.3f},{p[1]:.3f}"


def plain_xml(net: NetworkConfig) -> tuple[str, str]:
    """The `.nod.xml` and `.edg.xml` texts of the roundabout.

    Returns:
        (nodes_xml, edges_xml)
    """
    n = len(net.legs)
    r = net.ring_radius_m
    nodes = ["<nodes>"]
    for i, leg in enumerate(net.legs):
        cx, cy = _point(r, leg.angle_deg)
        ox, oy = _point(r + leg.length_m, leg.angle_deg)
        nodes.append(f'  <node id="c{i}" x="{cx:.3f}" y="{cy:.3f}" type="priority"/>')
        nodes.append(f'  <node id="o{i}" x="{ox:.3f}" y="{oy:.3f}" type="dead_end"/>')
    nodes.append("</nodes>")

    edges = ["<edges>"]
    for i, leg in enumerate(net.legs):
        speed = f"{leg.speed_limit_mps:.4f}"
        name = quoteattr(leg.name)
        edges.append(
            f'  <edge id="{in_edge(i)}" from="o{i}" to="c{i}" '
            f'numLanes="{leg.entry_lanes}" '
            f'speed="{speed}" priority="1" name={name}/>'
        )
        edges.append(
            f'  <edge id="{out_edge(i)}" from="c{i}" to="o{i}" '
            f'numLanes="{leg.exit_lanes}" '
            f'speed="{speed}" priority="1" name={name}/>'
        )
    for i, leg in enumerate(net.legs):
        a0 = leg.angle_deg
        a1 = net.legs[(i + 1) % n].angle_deg
        sweep = (a1 - a0) % 360.0
        k = max(4, int(sweep / 5.0))
        shape = " ".join(_fmt(_point(r, a0 + sweep * s / k)) for s in range(k + 1))
        edges.append(
            f'  <edge id="{ring_edge(i)}" from="c{i}" to="c{(i + 1) % n}" '
            f'numLanes="{net.ring_lanes}" '
            f'speed="{net.ring_speed_limit_mps:.4f}" priority="2" shape="{shape}"/>'
        )
    ring_nodes = " ".join(f"c{i}" for i in range(n))
    ring_edges = " ".join(ring_edge(i) for i in range(n))
    edges.append(f'  <roundabout nodes="{ring_nodes}" edges="{ring_edges}"/>')
    edges.append("</edges>")
    return "\n".join(nodes) + "\n", "\n".join(edges) + "\n"


def connections_xml(net: NetworkConfig) -> str | None:
    """The `.con.xml` text of the lane-to-lane joins at two-lane exits, or
    None where netconvert's own joins are kept (every exit has one lane).

    netconvert (1.28) joins a two-lane ring to a two-lane exit from the
    outer ring lane alone, fanning out to both exit lanes: a vehicle on the
    inner lane could not leave from it, though a two-lane exit is there for
    it. This file joins lane to lane as two-lane roundabouts are marked:
    outer ring lane to the exit's right lane, inner to its left one, and
    each ring lane on to the same lane of the next ring edge. netconvert
    computes no joins of its own for an edge given any, so every join of
    the ring edge that reaches a two-lane exit is listed; its right of way
    stays netconvert's (the inner lane's exit yields to the outer lane going
    on round, whose path it crosses).
    """
    n = len(net.legs)
    lines = []
    for j, leg in enumerate(net.legs):
        if leg.exit_lanes == 1:
            continue
        before, after = ring_edge((j - 1) % n), ring_edge(j)
        for lane in range(net.ring_lanes):
            for to in (after, out_edge(j)):
                lines.append(
                    f'  <connection from="{before}" to="{to}" '
                    f'fromLane="{lane}" toLane="{lane}"/>'
                )
    if not lines:
        return None
    return "<connections>\n" + "\n".join(lines) + "\n</connections>\n"


def build_network(net: NetworkConfig, out_dir: Path, stem: str) -> Path:
    """Write `<stem>.nod.xml`, `<stem>.edg.xml` (and `<stem>.con.xml` where
    `connections_xml` gives one) and compile `<stem>.net.xml`.

    Raises:
        RuntimeError: netconvert failed (its message is included).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    nod, edg = plain_xml(net)
    nod_path = out_dir / f"{stem}.nod.xml"
    edg_path = out_dir / f"{stem}.edg.xml"
    net_path = out_dir / f"{stem}.net.xml"
    nod_path.write_text(nod)
    edg_path.write_text(edg)
    inputs = ["--node-files", str(nod_path), "--edge-files", str(edg_path)]
    connections = connections_xml(net)
    if connections is not None:
        con_path = out_dir / f"{stem}.con.xml"
        con_path.write_text(connections)
        inputs += ["--connection-files", str(con_path)]
    cmd = [
        sumo_binary("netconvert"),
        *inputs,
        "--output-file", str(net_path),
        "--no-turnarounds", "true",
        "--roundabouts.guess", "false",
        "--junctions.limit-turn-speed", "-1",
        "--offset.disable-normalization", "true",
        "--no-warnings", "true",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0 or not net_path.exists():
        raise RuntimeError(f"netconvert failed:\n{done.stderr or done.stdout}")
    return net_path


def network_fingerprint(net: NetworkConfig) -> str:
    """Short hash of the network settings: all that netconvert's output
    depends on (scenarios that differ in demand or drivers share it)."""
    blob = json.dumps(net.to_dict(), sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def network_file(cfg: ScenarioConfig, workdir: str | Path | None = None) -> Path:
    """The scenario's `.net.xml`, built once per network and cached.

    The JAX side compiles it, and `sumo_export.scenario.write_scenario`
    copies it into each scenario folder. The cache lives in
    ``$XDG_CACHE_HOME/jaxround/networks/<name>-<network_fingerprint>``
    (``~/.cache`` by default); a network is built in a temporary folder and
    moved into place, so parallel processes never see half a file.
    """
    if workdir is None:
        cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        key = f"{cfg.name}-{network_fingerprint(cfg.network)}"
        workdir = cache / "jaxround" / "networks" / key
    workdir = Path(workdir)
    path = workdir / f"{cfg.name}.net.xml"
    if not path.exists():
        workdir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            built = build_network(cfg.network, Path(tmp), cfg.name)
            os.replace(built, path)
    return path
