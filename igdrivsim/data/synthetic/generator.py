"""Synthetic WOMD-format scenarios: a map, a cast of agents with interactions, planned logs.

``generate_scenario(seed, index, split)`` is deterministic: it draws everything from a NumPy
Generator seeded with ``(seed, split, index)``. Each scenario is a curved multi-lane road or an
intersection; the SDC meets at least one situation that needs anticipation (a stalled car around a
bend, a braking leader, a cut-in, cross traffic, pedestrians on a crosswalk). The SDC log is
checked: no overlap with any object and all four box corners inside the road edges.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    NUM_STEPS,
    RG_ROAD_EDGE_TYPES,
    TYPE_CYCLIST,
    TYPE_PEDESTRIAN,
    Capacities,
    Scenario,
    empty_scenario,
    encode_scenario_id,
    fit_to_capacities,
)
from igdrivsim.data.synthetic import geometry as geo
from igdrivsim.data.synthetic.agents import Agent, box_corners, collides, plan
from igdrivsim.data.synthetic.maps import (
    MapData,
    Route,
    intersection_map,
    lane_change_route,
    road_map,
)

SPLITS = {"training": 0, "validation": 1, "testing": 2}


@dataclass(frozen=True)
class GeneratorConfig:
    """Generator settings (paper-independent; the defaults give WOMD-like scenarios)."""

    seed: int = 0
    p_intersection: float = 0.5  # else a curved road
    roadgraph_spacing: float = 0.5  # m between roadgraph samples, as in WOMD
    origin_range: float = 2000.0  # maps are placed at a random global offset (m)
    max_attempts: int = 8  # re-draws when the SDC log would collide or leave the road
    max_objects: int = 128
    max_roadgraph_points: int = 20_000

    def to_dict(self) -> dict:
        return asdict(self)


def scenario_rng(seed: int, index: int, split: str = "training") -> np.random.Generator:
    return np.random.default_rng([int(seed), SPLITS[split], int(index)])


def _vehicle(rng, route: Route, s0: float, role: str, v_scale: float = 1.0, **kw) -> Agent:
    big = rng.random() < 0.08
    length = rng.uniform(6.5, 9.5) if big else float(np.clip(rng.normal(4.6, 0.35), 3.8, 5.6))
    width = rng.uniform(2.3, 2.6) if big else float(np.clip(rng.normal(1.95, 0.08), 1.7, 2.2))
    v_des = route.speed_limit * rng.uniform(0.85, 1.1) * v_scale
    a = Agent(route=route, s0=s0, v0=v_des * rng.uniform(0.6, 1.0), length=length, width=width,
              height=rng.uniform(2.5, 3.4) if big else rng.uniform(1.4, 1.9), v_des=v_des,
              accel=rng.uniform(1.2, 2.0), brake=rng.uniform(1.6, 2.6),
              headway=rng.uniform(1.1, 1.8), min_gap=rng.uniform(2.0, 3.5),
              lateral=(rng.uniform(0.0, 0.25), rng.uniform(40, 120), rng.uniform(0, 6.3)),
              role=role)
    for key, value in kw.items():
        setattr(a, key, value)
    if route.stop_at is not None and s0 < route.stop_at:  # able to stop comfortably in time
        room = max(route.stop_at - s0 - length / 2 - 1.0, 0.0)
        a.v0 = min(a.v0, float(np.sqrt(2 * 1.5 * room)))
    return a


def _sdc(rng, route: Route, s0: float) -> Agent:
    a = _vehicle(rng, route, s0, "sdc", is_sdc=True)
    a.length, a.width, a.height = 4.9, 2.1, 1.7  # a mid-size SUV
    a.accel, a.brake, a.headway = 1.4, 1.8, 1.6  # smooth and anticipating
    a.lateral = (rng.uniform(0.0, 0.12), rng.uniform(60, 150), rng.uniform(0, 6.3))
    return a


def _walker(rng, path: np.ndarray, static: bool = False) -> Agent:
    if rng.random() < 0.5:
        path = path[::-1]
    route = Route(geo.resample(path, 0.5), group=-1, kind="walk", speed_limit=1.5)
    size = rng.uniform(0.5, 0.9)
    s0 = 0.0 if static else rng.uniform(0, 3)
    return Agent(route=route, s0=s0, v0=0.0 if static else rng.uniform(1.0, 1.6),
                 length=size, width=size, height=rng.uniform(1.5, 1.9), obj_type=TYPE_PEDESTRIAN,
                 walker=True, static=static, start_step=int(rng.integers(0, 45)), role="walker")


def _cast_road(rng, m: MapData) -> list[Agent]:
    groups = sorted(m.lanes)
    g = int(rng.choice(groups))
    if m.dropped and rng.random() < 0.5:  # the SDC's lane ends ahead: it has to merge
        g = min(m.dropped)
    lane = next(r for r in m.routes if r.group == g)
    s0 = rng.uniform(50, 110)  # with road behind the SDC too
    neighbours = [h for h in groups if m.lanes[h][1] == m.lanes[g][1]
                  and abs(m.lanes[h][0] - m.lanes[g][0]) < 5]
    neighbours = [h for h in neighbours if h != g and h not in m.dropped]
    if g in m.dropped:  # the SDC's lane ends: it merges; no further lane change or cut-in
        neighbours = []
    route = lane
    if neighbours and rng.random() < 0.15:
        route = lane_change_route(m, g, int(rng.choice(neighbours)), s0 + rng.uniform(20, 60),
                                  rng.uniform(30, 50))
    agents = [_sdc(rng, route, s0)]
    for strip in m.parking:  # parked cars along the kerb
        at = rng.uniform(0, 12)
        while at < strip.s[-1] - 6:
            if rng.random() < 0.6:
                agents.append(_vehicle(rng, strip, at, "parked", static=True, v0=0.0))
            at += rng.uniform(6.5, 14)
    if rng.random() < 0.08:  # the SDC waits in a queue (filtered out by the speed criterion)
        agents[0].v0 = 0.0
        agents.append(_vehicle(rng, route, s0 + rng.uniform(7.0, 8.0), "stalled", static=True,
                               v0=0.0))
    elif rng.random() < 0.3:  # a stalled car around the next bend
        s = geo.arc_length(route.points)
        kappa = np.abs(geo.curvature(route.points))
        window = (s > s0 + 50) & (s < s0 + 120)
        at = s[window][np.argmax(kappa[window])] + rng.uniform(0, 25)
        agents.append(_vehicle(rng, route, at, "stalled", static=True, v0=0.0))
    if rng.random() < 0.5:  # a leader that brakes
        t0 = int(rng.integers(15, 55))
        agents.append(_vehicle(rng, route, s0 + rng.uniform(15, 45), "braking_leader",
                               stop_window=(t0, t0 + int(rng.integers(15, 60)))))
    if neighbours and rng.random() < 0.4:  # a cut-in from the next lane
        h = int(rng.choice(neighbours))
        at = s0 + rng.uniform(8, 30)
        cut = lane_change_route(m, h, g, at + rng.uniform(5, 25), rng.uniform(25, 45))
        v = agents[0].v0 * rng.uniform(0.95, 1.15)
        agents.append(_vehicle(rng, cut, at, "cut_in", v0=v, v_des=max(v, cut.speed_limit)))
    for walk in m.walk_paths:
        for _ in range(int(rng.integers(1, 4))):
            agents.append(_walker(rng, walk))
    for walk in m.sidewalks:  # pedestrians strolling or standing beside the road
        for _ in range(int(rng.integers(0, 3))):
            stroll = _walker(rng, walk, static=rng.random() < 0.3)
            stroll.s0 = rng.uniform(0, stroll.route.s[-1] - 20)
            stroll.start_step = 0
            agents.append(stroll)
    for h in groups:  # background traffic on every lane
        routes = [r for r in m.routes if r.group == h]
        for _ in range(int(rng.integers(0, 5))):
            agents.append(_vehicle(rng, routes[0], rng.uniform(0, routes[0].s[-1] - 40),
                                   "background"))
    if rng.random() < 0.15:
        right = min(groups, key=lambda h: (m.lanes[h][1] != m.lanes[g][1], m.lanes[h][0]))
        bike = _vehicle(rng, next(r for r in m.routes if r.group == right), rng.uniform(20, 120),
                        "cyclist", obj_type=TYPE_CYCLIST)
        bike.length, bike.width, bike.height = 1.8, 0.7, 1.7
        bike.v_des = bike.v0 = rng.uniform(4, 6)
        agents.append(bike)
    return agents


def _cast_intersection(rng, m: MapData) -> list[Agent]:
    route = m.routes[int(rng.integers(len(m.routes)))]
    # Closer to a stop sign, so that the stop, the wait and the crossing fit in the 9 s log.
    s0 = route.entry - (rng.uniform(10, 40) if route.stop_at is not None else rng.uniform(12, 70))
    sdc = _sdc(rng, route, s0)
    agents = [sdc]
    eta = (route.entry - s0) / max(sdc.v0, 3.0)
    groups = sorted({r.group for r in m.routes})
    for g in groups:
        routes = [r for r in m.routes if r.group == g]
        pick = lambda rs=routes: rs[int(rng.integers(len(rs)))]  # noqa: E731
        if g == route.group:
            if rng.random() < 0.45:
                agents.append(_vehicle(rng, pick(), s0 + rng.uniform(12, 40), "leader"))
            if rng.random() < 0.5:
                agents.append(_vehicle(rng, pick(), s0 - rng.uniform(12, 35), "follower"))
            continue
        if rng.random() < 0.75:  # cross traffic timed to meet the SDC at the junction
            r = pick()
            v = r.speed_limit * rng.uniform(0.6, 1.0)
            d = float(np.clip(v * (eta + rng.uniform(-2.5, 2.5)), 3, r.entry - 1))
            agents.append(_vehicle(rng, r, r.entry - d, "cross"))
            if rng.random() < 0.4:
                agents.append(_vehicle(rng, pick(), r.entry - d - rng.uniform(12, 35), "cross"))
        if rng.random() < 0.5:  # already through the junction, driving away
            r = pick()
            agents.append(_vehicle(rng, r, r.entry + rng.uniform(25, 60), "leaving"))
        if rng.random() < 0.4:  # further back on the approach
            r = pick()
            agents.append(_vehicle(rng, r, rng.uniform(0, r.entry - 60), "background"))
    for walk in m.walk_paths:
        if rng.random() < 0.4:
            agents.append(_walker(rng, walk))
        if rng.random() < 0.2:
            agents.append(_walker(rng, walk, static=True))
    return agents


def _priority(rng, agents: list[Agent]) -> list[Agent]:
    """Planning order: walkers and stalled cars, then lanes in random right-of-way order, and
    within a lane the vehicle in front first (cut-ins before the SDC)."""
    rank = {g: rng.random() for g in {a.route.group for a in agents}}

    def key(a: Agent):
        first = 0 if (a.walker or a.static) else 1 if a.role == "cut_in" else 2
        stop = a.route.stop_at is not None  # stop-sign approaches give way to the others
        return (first, stop, rank[a.route.group], -a.s0)

    return sorted(agents, key=key)


def _edges(m: MapData) -> tuple[cKDTree, np.ndarray]:
    pts, dirs = [], []
    for points, t in m.features:
        if t in RG_ROAD_EDGE_TYPES:
            p = geo.resample(points, 0.5)
            pts.append(p), dirs.append(geo.next_dirs(p))
    pts, dirs = np.concatenate(pts), np.concatenate(dirs)
    return cKDTree(pts), np.concatenate([pts, dirs], 1)


def offroad_steps(edges: tuple[cKDTree, np.ndarray], agent: Agent) -> np.ndarray:
    """Steps at which a box corner lies on the outer (right) side of the nearest edge point."""
    tree, table = edges
    corners = box_corners(agent.xy, agent.yaw, agent.length, agent.width)  # [T, 4, 2]
    _, idx = tree.query(corners.reshape(-1, 2))
    p, d = table[idx, :2], table[idx, 2:]
    rel = corners.reshape(-1, 2) - p
    cross = d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0]  # > 0: left of the edge (inside)
    return (cross < 0).reshape(-1, 4).any(1) & agent.valid


def _stage(rng, m: MapData, cast: list[Agent], edges) -> list[Agent] | None:
    planned: list[Agent] = []
    for agent in _priority(rng, cast):
        plan(agent, planned)
        if not agent.valid.any():
            continue
        if any(collides(agent, other) for other in planned):
            if agent.is_sdc:
                return None
            continue
        planned.append(agent)
    sdc = next((a for a in planned if a.is_sdc), None)
    if sdc is None or not sdc.valid.all() or offroad_steps(edges, sdc).any():
        return None
    return planned


def plan_scenario(rng: np.random.Generator, config: GeneratorConfig = GeneratorConfig()):
    """Draw a map and a cast and plan them: ``(map, agents)`` with ``agents[i].is_sdc`` once."""
    for _ in range(config.max_attempts):
        m = intersection_map(rng) if rng.random() < config.p_intersection else road_map(rng)
        edges = _edges(m)
        for _ in range(3):
            cast = _cast_intersection(rng, m) if m.kind == "intersection" else _cast_road(rng, m)
            planned = _stage(rng, m, cast, edges)
            if planned is not None:
                return m, planned
    raise RuntimeError("synthetic generator: no valid scenario after max_attempts draws")


def paths_intersect(xy_a: np.ndarray, valid_a: np.ndarray, xy_b: np.ndarray,
                    valid_b: np.ndarray) -> bool:
    """Whether two logged paths (segments between consecutive valid steps) cross or touch."""
    def segments(xy, valid):
        ok = valid[:-1] & valid[1:]
        return xy[:-1][ok], xy[1:][ok]

    a0, a1 = segments(xy_a, valid_a)
    b0, b1 = segments(xy_b, valid_b)
    if len(a0) == 0 or len(b0) == 0:
        return False
    lo_a, hi_a = np.minimum(a0, a1), np.maximum(a0, a1)
    lo_b, hi_b = np.minimum(b0, b1), np.maximum(b0, b1)
    if np.any(hi_a.max(0) < lo_b.min(0)) or np.any(hi_b.max(0) < lo_a.min(0)):
        return False
    p, r = a0[:, None], (a1 - a0)[:, None]
    q, s = b0[None], (b1 - b0)[None]
    cross = lambda u, v: u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]  # noqa: E731
    den = cross(r, s)
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross(qp, s) / den
        u = cross(qp, r) / den
    hit = (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    return bool(hit.any())


def to_scenario(rng: np.random.Generator, m: MapData, agents: list[Agent], scenario_id: str,
                config: GeneratorConfig = GeneratorConfig()) -> Scenario:
    """Place the planned map and agents at a random global pose and pack a :class:`Scenario`."""
    caps = Capacities(max_objects=config.max_objects,
                      max_roadgraph_points=config.max_roadgraph_points)
    order = rng.permutation(len(agents))
    agents = [agents[i] for i in order]
    # Like a perception log, objects are valid only within sensor range of the SDC.
    sdc_xy = next(a.xy for a in agents if a.is_sdc)
    sensor = rng.uniform(90, 130)
    seen = [a.valid & (np.linalg.norm(a.xy - sdc_xy, axis=1) <= sensor) for a in agents]
    keep = [k for k, a in enumerate(agents) if seen[k].any() or a.is_sdc]
    agents, seen = [agents[k] for k in keep], [seen[k] for k in keep]
    if len(agents) > caps.max_objects:  # keep the SDC and the objects nearest to it
        near = np.argsort([np.linalg.norm(a.xy - sdc_xy, axis=1).min() for a in agents])
        chosen = np.sort(near[: caps.max_objects])
        agents, seen = [agents[k] for k in chosen], [seen[k] for k in chosen]
    n = len(agents)
    if n > caps.max_objects or not any(a.is_sdc for a in agents):
        raise RuntimeError("synthetic generator: SDC lost while packing objects")
    angle = rng.uniform(-np.pi, np.pi)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    origin = rng.uniform(-config.origin_range, config.origin_range, 2)
    z0 = rng.uniform(-20, 60)
    place = lambda xy: xy @ rot.T + origin  # noqa: E731

    out = empty_scenario(Capacities(max_objects=n, max_roadgraph_points=1,
                                    max_traffic_lights=caps.max_traffic_lights))
    tr = out.trajectory
    xy = np.stack([place(a.xy) for a in agents])  # [n, T, 2]
    valid = np.stack(seen)
    vel = np.gradient(xy, 0.1, axis=1)
    vel[~valid] = 0
    yaw = np.stack([a.yaw for a in agents]) + angle
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    f32 = lambda v: np.where(valid, v, 0).astype(np.float32)  # noqa: E731
    size = lambda name: np.repeat(np.array([getattr(a, name) for a in agents])[:, None],  # noqa: E731
                                  NUM_STEPS, 1)
    tr = tr.replace(x=f32(xy[..., 0]), y=f32(xy[..., 1]),
                    z=f32(z0 + size("height") / 2), yaw=f32(yaw), vel_x=f32(vel[..., 0]),
                    vel_y=f32(vel[..., 1]), length=f32(size("length")), width=f32(size("width")),
                    height=f32(size("height")), valid=valid)
    sdc = int(np.flatnonzero([a.is_sdc for a in agents])[0])
    interacting = [i for i in range(n) if i != sdc and paths_intersect(
        xy[sdc], valid[sdc], xy[i], valid[i])]
    at_now = np.linalg.norm(xy[:, CURRENT_INDEX] - xy[sdc, CURRENT_INDEX], axis=1)
    at_now = np.where(valid[:, CURRENT_INDEX] & (valid.sum(1) > 20), at_now, np.inf)
    predict = np.zeros(n, bool)
    predict[np.argsort(at_now)[:8]] = np.isfinite(np.sort(at_now)[:8])
    interest = np.zeros(n, bool)
    if interacting:
        closest = min(interacting, key=lambda i: at_now[i])
        interest[[sdc, closest]] = True
    md = out.metadata.replace(
        id=rng.choice(np.arange(1, 10_000), n, replace=False).astype(np.int32),
        object_type=np.array([a.obj_type for a in agents], np.int32),
        is_sdc=np.arange(n) == sdc, tracks_to_predict=predict, objects_of_interest=interest,
        valid=valid.any(1))
    pts, dirs, types, ids = [], [], [], []
    base = int(rng.integers(100, 5000))
    for k, (points, t) in enumerate(m.features):
        p = geo.resample(points, config.roadgraph_spacing)
        d = geo.next_dirs(p)
        pts.append(place(p)), dirs.append(d @ rot.T)
        types.append(np.full(len(p), t)), ids.append(np.full(len(p), base + k))
    pts, dirs = np.concatenate(pts), np.concatenate(dirs)
    r = len(pts)
    rg = out.roadgraph.replace(
        xyz=np.concatenate([pts, np.full((r, 1), z0)], 1).astype(np.float32),
        dir=np.concatenate([dirs, np.zeros((r, 1))], 1).astype(np.float32),
        type=np.concatenate(types).astype(np.int32), id=np.concatenate(ids).astype(np.int32),
        valid=np.ones(r, bool))
    scenario = out.replace(trajectory=tr, metadata=md, roadgraph=rg,
                           scenario_id=encode_scenario_id(scenario_id))
    return fit_to_capacities(scenario, caps)


def scenario_name(seed: int, index: int, split: str) -> str:
    return f"syn{seed:x}{split[0]}{index:08d}"


def generate_scenario(seed: int, index: int, split: str = "training",
                      config: GeneratorConfig = GeneratorConfig()) -> Scenario:
    """The ``index``-th synthetic scenario of ``split`` for ``seed`` (deterministic)."""
    rng = scenario_rng(seed, index, split)
    m, agents = plan_scenario(rng, config)
    return to_scenario(rng, m, agents, scenario_name(seed, index, split), config)
