"""Small constructed scenarios for tests and the benchmark (no data files needed).

:func:`straight_road` builds a straight road along +x bounded by two road edges (interior on
their left), an SDC driving at constant speed on it, and a few other vehicles.
"""

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


def add_polyline(sc: Scenario, start: int, xy: np.ndarray, rg_type: int, poly_id: int) -> int:
    """Write polyline ``xy [N, 2]`` at slot ``start`` (dir to the next point); -> next slot."""
    rg = sc.roadgraph
    n = len(xy)
    d = np.zeros((n, 2), np.float32)
    seg = np.diff(xy, axis=0)
    d[:-1] = seg / np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-9)
    sl = slice(start, start + n)
    rg.xyz[sl, :2], rg.xyz[sl, 2] = xy, 0.0
    rg.dir[sl, :2], rg.dir[sl, 2] = d, 0.0
    rg.type[sl], rg.id[sl], rg.valid[sl] = rg_type, poly_id, True
    return start + n


def set_object(sc: Scenario, slot: int, x, y, yaw, *, length=4.5, width=2.0, sdc=False,
               valid=None) -> None:
    """Set object ``slot``'s trajectory from arrays (or scalars) over the 91 steps."""
    tr, md = sc.trajectory, sc.metadata
    t = np.arange(NUM_STEPS)
    x = np.broadcast_to(np.asarray(x, np.float32), t.shape)
    y = np.broadcast_to(np.asarray(y, np.float32), t.shape)
    yaw = np.broadcast_to(np.asarray(yaw, np.float32), t.shape)
    tr.x[slot], tr.y[slot], tr.yaw[slot] = x, y, yaw
    vx, vy = np.gradient(x) / 0.1, np.gradient(y) / 0.1
    tr.vel_x[slot], tr.vel_y[slot] = vx, vy
    tr.length[slot], tr.width[slot], tr.height[slot] = length, width, 1.5
    tr.valid[slot] = True if valid is None else valid
    md.id[slot], md.object_type[slot], md.valid[slot] = slot, TYPE_VEHICLE, True
    md.is_sdc[slot] = sdc


TOY_CAPS = Capacities(max_objects=8, max_roadgraph_points=600)


def straight_road(caps: Capacities = TOY_CAPS,
                  speed: float = 10.0, half_width: float = 5.0, spacing: float = 1.0,
                  scenario_id: str = "toy-straight") -> Scenario:
    """A straight road ``y in [-half_width, half_width]``, SDC (slot 0) along ``y = 0`` at
    ``speed`` m/s from ``x = -10``; slot 1 a car ahead in the same lane at the same speed; slot
    2 a parked car on the other side. Roadgraph: centre line + the two edges."""
    sc = empty_scenario(caps)
    t = np.arange(NUM_STEPS) * 0.1
    set_object(sc, 0, -10.0 + speed * t, 0.0, 0.0, sdc=True)
    set_object(sc, 1, 10.0 + speed * t, 0.0, 0.0)
    set_object(sc, 2, 40.0, -3.0, np.pi)
    n = (caps.max_roadgraph_points // 3)
    xs = -30.0 + spacing * np.arange(n, dtype=np.float32)
    i = add_polyline(sc, 0, np.stack([xs, np.zeros_like(xs)], 1), RG_LANE_SURFACE_STREET, 1)
    # Right edge runs +x (interior, y > -hw, on its left); left edge runs -x.
    i = add_polyline(sc, i, np.stack([xs, np.full_like(xs, -half_width)], 1),
                     RG_ROAD_EDGE_BOUNDARY, 2)
    add_polyline(sc, i, np.stack([xs[::-1], np.full_like(xs, half_width)], 1),
                 RG_ROAD_EDGE_BOUNDARY, 3)
    sc = sc.replace(scenario_id=encode_scenario_id(scenario_id))
    return sc
