"""Write a SUMO scenario (network, routes, .sumocfg) from a config and a schedule."""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from jaxround.scenario.config import DriverConfig, ScenarioConfig
from jaxround.scenario.edges import route_edges
from jaxround.scenario.schedule import Schedule
from jaxround.sumo_files.netconvert import connections_xml, network_file, plain_xml

HV_TYPE = "hv"
AV_TYPE = "av"


@dataclass(frozen=True)
class ScenarioFiles:
    """Paths of one written scenario."""

    net: Path
    routes: Path
    sumocfg: Path


def vehicle_id(index: int) -> str:
    """SUMO id of the schedule's vehicle `index` (ids sort like the schedule)."""
    return f"v{index:05d}"


def route_id(origin: int, destination: int) -> str:
    return f"r_{origin}_{destination}"


def action_step(driver: DriverConfig, dt_s: float) -> float:
    """The action step SUMO really uses: floored to a multiple of the step length."""
    return max(1, math.floor(driver.action_step_length / dt_s + 1e-9)) * dt_s


def vtype_xml(type_id: str, d: DriverConfig, dt_s: float) -> str:
    """A `<vType>` element for a driver class.

    The desired-speed factor is drawn per vehicle in the schedule, so the type's
    own speed distribution is switched off (speedDev 0).
    """
    attrs = {
        "id": type_id,
        "carFollowModel": d.car_follow_model,
        "accel": d.accel,
        "decel": d.decel,
        "emergencyDecel": d.emergency_decel,
        "apparentDecel": d.decel,
        "tau": d.tau,
        "minGap": d.min_gap,
        "length": d.length,
        "maxSpeed": d.max_speed,
        "speedDev": 0,
        "actionStepLength": action_step(d, dt_s),
        "jmTimegapMinor": d.jm_timegap_minor,
        "impatience": d.impatience,
        "jmCrossingGap": d.jm_crossing_gap,
        "emissionClass": d.emission_class,
        "color": "0,160,255" if type_id == AV_TYPE else "255,200,0",
    }
    if d.car_follow_model == "IDM":
        attrs["delta"] = d.delta
    else:
        attrs["sigma"] = d.sigma
    body = " ".join(f"{k}={quoteattr(_num(v))}" for k, v in attrs.items())
    return f"  <vType {body}/>"


def routes_xml(cfg: ScenarioConfig, schedule: Schedule) -> str:
    """The `.rou.xml` text: two vTypes, one route per OD pair, one vehicle per row.

    A vehicle departs on its entry's only lane (``departLane="first"``), or
    on a two-lane entry on SUMO's ``"best"`` lane: the one it can follow
    furthest along its route without changing, the emptier of equals.
    """
    n_legs = cfg.n_legs
    dt = cfg.simulation.dt_s
    lines = ["<routes>"]
    lines.append(vtype_xml(HV_TYPE, cfg.drivers.hv, dt))
    lines.append(vtype_xml(AV_TYPE, cfg.drivers.av, dt))
    for o in range(n_legs):
        for d in range(n_legs):
            if o != d:
                edges = " ".join(route_edges(o, d, n_legs))
                lines.append(f'  <route id="{route_id(o, d)}" edges="{edges}"/>')
    is_av = schedule.is_av
    speed_factor = schedule.class_speed_factors(
        cfg.drivers.hv.speed_dev, cfg.drivers.av.speed_dev
    )
    depart_lane = [
        "first" if leg.entry_lanes == 1 else "best" for leg in cfg.network.legs
    ]
    for i in range(schedule.n_vehicles):
        vtype = AV_TYPE if is_av[i] else HV_TYPE
        origin = schedule.origin[i]
        lines.append(
            f'  <vehicle id="{vehicle_id(i)}" type="{vtype}" '
            f'route="{route_id(origin, schedule.destination[i])}" '
            f'depart="{schedule.depart_s[i]:.2f}" departSpeed="max" '
            f'departLane="{depart_lane[origin]}" '
            f'departPos="base" speedFactor="{speed_factor[i]:.4f}"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def sumocfg_xml(cfg: ScenarioConfig, net: Path, routes: Path) -> str:
    """A `.sumocfg` that opens the scenario in sumo-gui with the runner's settings."""
    return f"""<configuration>
  <input>
    <net-file value="{net.name}"/>
    <route-files value="{routes.name}"/>
  </input>
  <time>
    <begin value="0"/>
    <step-length value="{cfg.simulation.dt_s}"/>
  </time>
  <processing>
    <collision.check-junctions value="true"/>
    <collision.action value="warn"/>
    <time-to-teleport value="300"/>
    <step-method.ballistic value="false"/>
  </processing>
  <random_number>
    <seed value="{cfg.simulation.seed}"/>
  </random_number>
</configuration>
"""


def write_scenario(
    cfg: ScenarioConfig, schedule: Schedule, out_dir: Path
) -> ScenarioFiles:
    """Write `<name>.net.xml`, `<name>.rou.xml` and `<name>.sumocfg` into `out_dir`.

    The network is netconvert's once per network
    (`jaxround.sumo_files.netconvert.network_file`, the JAX side's cache),
    copied here beside its plain XML (`<name>.nod.xml`, `<name>.edg.xml`,
    and `<name>.con.xml` where two-lane exits have their lanes joined),
    so that the folder opens alone in sumo-gui. Also writes the schedule as
    `<name>.schedule.npz` for the JAX side.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = cfg.name
    net = out_dir / f"{stem}.net.xml"
    shutil.copyfile(network_file(cfg), net)
    nodes, edges = plain_xml(cfg.network)
    (out_dir / f"{stem}.nod.xml").write_text(nodes)
    (out_dir / f"{stem}.edg.xml").write_text(edges)
    connections = connections_xml(cfg.network)
    if connections is not None:
        (out_dir / f"{stem}.con.xml").write_text(connections)
    routes = out_dir / f"{stem}.rou.xml"
    routes.write_text(routes_xml(cfg, schedule))
    sumocfg = out_dir / f"{stem}.sumocfg"
    sumocfg.write_text(sumocfg_xml(cfg, net, routes))
    schedule.save(out_dir / f"{stem}.schedule.npz")
    return ScenarioFiles(net=net, routes=routes, sumocfg=sumocfg)


def _num(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)
