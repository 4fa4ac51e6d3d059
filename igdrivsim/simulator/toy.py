"""Small constructed scenarios for tests and the benchmark (no data files needed)."""

from __future__ import annotations

import numpy as np

from igdrivsim.data.scenario import (
    NUM_STEPS,
    RG_LANE_SURFACE_STREET,
    RG_ROAD_EDGE_BOUNDARY,
    TYPE_VEHICLE,
    Capacities,
    Scenario,
    empty_scenario,
    encode_scenario_id,
)
from igdrivsim.data.synthetic.geometry import next_dirs


def add_polyline(sc: Scenario, start: int, xy: np.ndarray, rg_type: int, poly_id: int) -> int:
    """Write polyline ``xy [N, 2]`` at slot ``start`` (dir to the next point); -> next slot."""
    rg = sc.roadgraph
    sl = slice(start, start + len(xy))
    rg.xyz[sl, :2], rg.xyz[sl, 2] = xy, 0.0
    rg.dir[sl, :2], rg.dir[sl, 2] = next_dirs(xy), 0.0
    rg.type[sl], rg.id[sl], rg.valid[sl] = rg_type, poly_id, True
    return sl.stop


def set_object(sc: Scenario, slot: int, x, y, yaw, *, length=4.5, width=2.0, sdc=False,
               valid=None) -> None:
    """Set object ``slot``'s trajectory from arrays (or scalars) over the 91 steps."""
    tr, md = sc.trajectory, sc.metadata
    t = np.arange(NUM_STEPS)
    x, y, yaw = (np.broadcast_to(np.asarray(a, np.float32), t.shape) for a in (x, y, yaw))
    tr.x[slot], tr.y[slot], tr.yaw[slot] = x, y, yaw
    tr.vel_x[slot], tr.vel_y[slot] = np.gradient(x) / 0.1, np.gradient(y) / 0.1
    tr.length[slot], tr.width[slot], tr.height[slot] = length, width, 1.5
    tr.valid[slot] = True if valid is None else valid
    md.id[slot], md.object_type[slot], md.valid[slot] = slot, TYPE_VEHICLE, True
    md.is_sdc[slot] = sdc


TOY_CAPS = Capacities(max_objects=8, max_roadgraph_points=600)


def straight_road(caps: Capacities = TOY_CAPS, speed: float = 10.0, half_width: float = 5.0,
                  scenario_id: str = "toy-straight") -> Scenario:
    """A straight road ``y in [-half_width, half_width]``, SDC (slot 0) along ``y = 0`` at
    ``speed`` m/s from ``x = -10``; slot 1 a car ahead in the same lane at the same speed; slot
    2 a parked car on the other side. Roadgraph: centre line + the two edges."""
    sc = empty_scenario(caps)
    t = np.arange(NUM_STEPS) * 0.1
    set_object(sc, 0, -10.0 + speed * t, 0.0, 0.0, sdc=True)
    set_object(sc, 1, 10.0 + speed * t, 0.0, 0.0)
    set_object(sc, 2, 40.0, -3.0, np.pi)
    n = caps.max_roadgraph_points // 3
    xs = -30.0 + np.arange(n, dtype=np.float32)
    i = add_polyline(sc, 0, np.stack([xs, np.zeros_like(xs)], 1), RG_LANE_SURFACE_STREET, 1)
    # Right edge runs +x (interior, y > -hw, on its left); left edge runs -x.
    i = add_polyline(sc, i, np.stack([xs, np.full_like(xs, -half_width)], 1),
                     RG_ROAD_EDGE_BOUNDARY, 2)
    add_polyline(sc, i, np.stack([xs[::-1], np.full_like(xs, half_width)], 1),
                 RG_ROAD_EDGE_BOUNDARY, 3)
    return sc.replace(scenario_id=encode_scenario_id(scenario_id))


def following(gap: float = 40.0, speed: float = 10.0, leader_speed: float = 0.0,
              scenario_id: str = "toy-following") -> Scenario:
    """Slot 1 a car driving along ``y = 0`` at ``speed`` from ``x = 0`` (its log runs through
    whatever is ahead); slot 2 a car ``gap`` m ahead (centre to centre) at ``leader_speed``;
    the SDC (slot 0) parked out of the way at ``y = -30``. Roadgraph as :func:`straight_road`."""
    sc = straight_road(scenario_id=scenario_id)
    t = (np.arange(NUM_STEPS) - 10) * 0.1
    set_object(sc, 0, -50.0, -30.0, 0.0, sdc=True)
    set_object(sc, 1, speed * t, 0.0, 0.0)
    set_object(sc, 2, gap + leader_speed * t, 0.0, 0.0)
    return sc


def curve(radius: float = 40.0, start_speed: float = 4.0, log_speed: float = 20.0) -> Scenario:
    """Slot 1 a car on a circle of ``radius`` (counter-clockwise from ``(0, -radius)``),
    ``start_speed`` up to step 11 then ``log_speed``; the SDC parked far away."""
    sc = straight_road(scenario_id="toy-curve")
    steps = np.arange(NUM_STEPS)
    v = np.where(steps <= 10, start_speed, log_speed)
    arc = np.concatenate([[0.0], np.cumsum(v[:-1] * 0.1)]) - 10 * start_speed * 0.1
    ang = arc / radius
    set_object(sc, 0, -500.0, -500.0, 0.0, sdc=True)
    set_object(sc, 1, radius * np.sin(ang), -radius * np.cos(ang), ang)
    set_object(sc, 2, 0.0, 0.0, 0.0, valid=np.zeros(NUM_STEPS, bool))
    return sc


def red_light(stop_x: float = 40.0, speed: float = 10.0) -> Scenario:
    """:func:`following` without the car ahead, with a light always red at ``(stop_x, 0)``."""
    sc = following(speed=speed, scenario_id="toy-red-light")
    sc.trajectory.valid[2] = False
    tl = sc.traffic_lights
    tl.state[0], tl.valid[0], tl.x[0], tl.y[0] = 4, True, stop_x, 0.0  # LANE_STATE_STOP
    return sc
