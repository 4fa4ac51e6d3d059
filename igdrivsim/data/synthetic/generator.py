"""Synthetic WOMD-format scenarios: a map (curved road or intersection), a cast of agents with
interactions that need anticipation, and their planned logs (docs/synthetic.md).

``generate_scenario(seed, index, split)`` draws everything from a NumPy Generator seeded with
``(seed, split, index)``. The SDC log never overlaps an object and stays inside the road edges.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Literal

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
from igdrivsim.data.synthetic import agents as ag
from igdrivsim.data.synthetic import geometry as geo
from igdrivsim.data.synthetic.agents import Agent, collides_any, plan, stop_cap
from igdrivsim.data.synthetic.maps import (
    LIGHT_GO,
    LIGHT_STOP,
    MapData,
    Route,
    intersection_map,
    lane_change_route,
    road_map,
)
from igdrivsim.data.synthetic.motion import (
    JUNCTION_SKEW,
    MOTIONS,
    ROAD_BEND,
    calibrate_cast,
    calibrate_map,
)
from igdrivsim.data.synthetic.plot import SPLIT_LETTERS

SPLITS = {"training": 0, "validation": 1, "testing": 2}


@dataclass(frozen=True)
class GeneratorConfig:
    """Generator settings (paper-independent; the defaults give WOMD-like scenarios)."""

    seed: int = 0
    p_intersection: float = 0.6  # else a curved road
    roadgraph_spacing: float = 0.5  # m between roadgraph samples, as in WOMD
    origin_range: float = 2000.0  # maps are placed at a random global offset (m)
    max_attempts: int = 8  # re-draws when the SDC log would collide or leave the road
    max_objects: int = 128
    max_roadgraph_points: int = 20_000
    motion: Literal["default", "calibrated"] = "default"  # calibrated: towards real logs

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise ValueError(f"motion must be one of {MOTIONS}, got {self.motion!r}")

    def to_dict(self) -> dict:
        """The fields (``motion`` only when not the default: older folders stay resumable)."""
        return {k: v for k, v in asdict(self).items() if k != "motion" or v != "default"}


def scenario_rng(seed: int, index: int, split: str = "training") -> np.random.Generator:
    return np.random.default_rng([int(seed), SPLITS[split], int(index)])


def _vehicle(rng, route: Route, s0: float, role: str, **kw) -> Agent:
    big = rng.random() < 0.08
    # min(max()) on a float: np.clip's value, without its overhead
    length = rng.uniform(6.5, 9.5) if big else min(max(rng.normal(4.6, 0.35), 3.8), 5.6)
    width = rng.uniform(2.3, 2.6) if big else min(max(rng.normal(1.95, 0.08), 1.7), 2.2)
    v_des = route.speed_limit * rng.uniform(0.85, 1.1)
    a = Agent(route=route, s0=s0, v0=v_des * rng.uniform(0.6, 1.0), length=length, width=width,
              height=rng.uniform(2.5, 3.4) if big else rng.uniform(1.4, 1.9), v_des=v_des,
              accel=rng.uniform(1.2, 2.0), brake=rng.uniform(1.6, 2.6),
              headway=rng.uniform(1.1, 1.8), min_gap=rng.uniform(2.0, 3.5),
              lateral=(rng.uniform(0.0, 0.25), rng.uniform(40, 120), rng.uniform(0, 6.3)),
              role=role)
    a = replace(a, **kw)  # the caller's settings over the drawn ones
    a.v0 = min(a.v0, stop_cap(a))
    return a


def _parked(rng, strips: list[Route], walks: list[np.ndarray], fill: float = 0.8) -> list[Agent]:
    """Cars parked along kerbside strips (about one per 6-9 m), clear of the crosswalks."""
    out = []
    for strip in strips:
        at = rng.uniform(0, 6)
        while at < strip.s[-1] - 4:
            xy = strip.points[min(int(at), len(strip.points) - 1)]
            clear = all(_segment_distance(xy, a, b) > 6.0 for a, b in walks)
            if clear and rng.random() < fill:
                out.append(_vehicle(rng, strip, at, "parked", static=True, v0=0.0))
            at += rng.uniform(6.3, 9.0)
    return out


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    u = float(np.clip((p - a) @ ab / max(ab @ ab, 1e-9), 0, 1))
    return float(np.linalg.norm(p - a - u * ab))


def _queue(rng, route: Route, count: tuple[int, int]) -> list[Agent]:
    """Vehicles standing in a row behind the route's signal; static if it stays red."""
    out, front = [], route.signal_at - rng.uniform(0.6, 1.2)
    stays = (route.signal == LIGHT_STOP).all()
    for _ in range(int(rng.integers(*count))):
        a = _vehicle(rng, route, 0.0, "queued", v0=0.0, static=stays)
        a.s0 = front - a.length / 2
        if a.s0 < 5:
            break
        out.append(a)
        front = a.s0 - a.length / 2 - rng.uniform(1.8, 3.2)
    return out


def _walkers(rng, m: MapData, crossing: tuple[int, int], strolling: tuple[int, int]
             ) -> list[Agent]:
    """Pedestrians on the crosswalks (at signals: while the cars have red) and the sidewalks."""
    out = []
    for walk, steps in zip(m.walk_paths, m.walk_steps, strict=True):
        for _ in range(int(rng.integers(*crossing))):
            p = _walker(rng, walk, m.cache)
            if steps is not None:
                if not len(steps):
                    continue
                p.start_step = int(rng.choice(steps[: max(len(steps) // 2, 1)]))
            out.append(p)
    for walk in m.sidewalks:
        for _ in range(int(rng.integers(*strolling))):
            stroll = _walker(rng, walk, m.cache, static=rng.random() < 0.4)
            stroll.s0 = rng.uniform(0, max(stroll.route.s[-1] - 20, 1.0))
            stroll.start_step, stroll.role = 0, "stroller"
            out.append(stroll)
    return out


def _sdc(rng, route: Route, s0: float) -> Agent:
    a = _vehicle(rng, route, s0, "sdc", is_sdc=True)
    a.length, a.width, a.height = 4.9, 2.1, 1.7  # a mid-size SUV
    a.accel, a.brake, a.headway = 1.4, 1.8, 1.6  # smooth and anticipating
    a.lateral = (rng.uniform(0.0, 0.12), rng.uniform(60, 150), rng.uniform(0, 6.3))
    return a


def _walker(rng, path: np.ndarray, routes: dict, static: bool = False) -> Agent:
    """A pedestrian along ``path`` (either way); ``routes`` caches the walk routes of a map."""
    flip = rng.random() < 0.5
    key = ("walk", id(path), flip)  # the map holds its paths: their ids stay theirs
    if key not in routes:
        routes[key] = Route(geo.resample(path[::-1] if flip else path, 0.5), group=-1,
                            kind="walk", speed_limit=1.5)
    size = rng.uniform(0.5, 0.9)
    return Agent(route=routes[key], s0=0.0 if static else rng.uniform(0, 3),
                 v0=0.0 if static else rng.uniform(1.0, 1.6),
                 length=size, width=size, height=rng.uniform(1.5, 1.9), obj_type=TYPE_PEDESTRIAN,
                 walker=True, static=static, start_step=int(rng.integers(0, 45)), role="walker")


def _cast_road(rng, m: MapData) -> list[Agent]:
    groups = sorted(m.lanes)
    kerb = min((h for h in groups if m.lanes[h][1] > 0 and h not in m.dropped),
               key=lambda h: m.lanes[h][0])  # rightmost forward lane
    g = kerb if rng.random() < 0.6 else int(rng.choice(groups))
    if m.dropped and rng.random() < 0.5:  # the SDC's lane ends ahead: it has to merge
        g = min(m.dropped)
    lane = next(r for r in m.routes if r.group == g)
    s0 = rng.uniform(50, 110)  # with road behind the SDC too
    if m.no_parking and rng.random() < 0.9:  # near the side street
        mouth = m.no_parking[int(rng.integers(len(m.no_parking)))].mean(0)
        at = lane.s[np.argmin(np.linalg.norm(lane.points - mouth, axis=1))]
        s0 = float(np.clip(at - rng.uniform(-20, 45), 30, lane.s[-1] - 150))
    # next lanes (none when the SDC's lane ends: it merges; no further lane change or cut-in)
    neighbours = [h for h in groups if m.lanes[h][1] == m.lanes[g][1] and h != g
                  and abs(m.lanes[h][0] - m.lanes[g][0]) < 5 and h not in m.dropped
                  and g not in m.dropped]
    route = lane
    if neighbours and rng.random() < 0.15:
        route = lane_change_route(m, g, int(rng.choice(neighbours)), s0 + rng.uniform(20, 60),
                                  rng.uniform(30, 50))
    sdc = _sdc(rng, route, s0)
    agents = [sdc, *_parked(rng, m.parking, m.walk_paths + m.no_parking)]
    for r in m.routes:  # traffic turning into and out of the side street
        if r.group >= 100 and rng.random() < 0.5:
            agents.append(_vehicle(rng, r, rng.uniform(0, max(r.s[-1] - 80, 1.0)), "side"))
    if rng.random() < 0.08:  # the SDC waits in a queue (filtered out by the speed criterion)
        sdc.v0 = 0.0
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
        v = sdc.v0 * rng.uniform(0.95, 1.15)
        agents.append(_vehicle(rng, cut, at, "cut_in", v0=v, v_des=max(v, cut.speed_limit)))
    if neighbours and rng.random() < 0.85:  # a car alongside in the next lane
        h = int(rng.choice(neighbours))
        r = next(r for r in m.routes if r.group == h)
        agents.append(_vehicle(rng, r, s0 + rng.uniform(-6, 6), "alongside",
                               v0=sdc.v0 * rng.uniform(0.9, 1.1)))
    agents += _walkers(rng, m, (1, 4), (1, 6))
    start = route.points[min(int(s0), len(route.points) - 1)]
    for h in groups:  # traffic on every lane near the SDC, queued at a red light
        r = next(r for r in m.routes if r.group == h)
        near = np.flatnonzero(np.linalg.norm(r.points - start, axis=1) < 80)
        if not len(near):
            continue
        lo, hi = r.s[near[0]], r.s[near[-1]]
        if r.signal is not None and r.signal[0] != LIGHT_GO:
            queue = _queue(rng, r, (0, 5))
            agents += [a for a in queue if h != g or a.s0 > s0 + 10]
        at = lo + rng.uniform(0, 30)
        while at < min(hi, r.s[-1] - 40):
            agents.append(_vehicle(rng, r, at, "background"))
            at += rng.uniform(35, 90)
    cycles = [r for r in m.bike_routes if rng.random() < 0.5]
    if rng.random() < 0.15:
        right = min(groups, key=lambda h: (m.lanes[h][1] != m.lanes[g][1], m.lanes[h][0]))
        cycles.append(next(r for r in m.routes if r.group == right))
    for r in cycles:
        bike = _vehicle(rng, r, rng.uniform(20, 120), "cyclist", obj_type=TYPE_CYCLIST)
        bike.length, bike.width, bike.height = 1.8, 0.7, 1.7
        bike.v_des = bike.v0 = rng.uniform(4, 6)
        agents.append(bike)
    return agents


def _cast_intersection(rng, m: MapData) -> list[Agent]:
    kerb = [r for r in m.routes if r.lane == 0] if rng.random() < 0.65 else m.routes
    if rng.random() < 0.7:  # mostly through a green light (a red one: often a standing SDC)
        kerb = [r for r in kerb if r.signal is None or r.signal[0] == LIGHT_GO] or kerb
    route = kerb[int(rng.integers(len(kerb)))]
    # Closer to a stop sign, so that the stop, the wait and the crossing fit in the 9 s log.
    s0 = route.entry - (rng.uniform(10, 40) if route.stop_at is not None else rng.uniform(8, 40))
    sdc = _sdc(rng, route, s0)
    agents = [sdc, *_parked(rng, m.parking, m.walk_paths, fill=0.85),
              *_walkers(rng, m, (0, 3), (1, 4))]
    eta = (route.entry - s0) / max(sdc.v0, 3.0)
    for g in sorted({r.group for r in m.routes}):
        routes = [r for r in m.routes if r.group == g]
        pick = lambda rs=routes: rs[int(rng.integers(len(rs)))]
        red = routes[0].signal is not None and routes[0].signal[0] != LIGHT_GO
        if red:  # a queue at the red light (behind it the SDC, on its own lane)
            queue = _queue(rng, pick(), (1, 6))
            if g == route.group:
                queue = [a for a in queue if a.s0 > s0 + 12]
            for a in queue:
                a.route = pick() if not a.static else a.route
            agents += queue
        if g != route.group and np.linalg.norm(routes[0].points[0] - route.points[0]) < 4.5:
            if rng.random() < 0.85:  # alongside the SDC in the next approach lane
                agents.append(_vehicle(rng, pick(), s0 + rng.uniform(-6, 6), "alongside",
                                       v0=sdc.v0 * rng.uniform(0.9, 1.1)))
            continue
        if g == route.group:
            if not red and rng.random() < 0.6:
                agents.append(_vehicle(rng, pick(), s0 + rng.uniform(12, 40), "leader"))
            if rng.random() < 0.6:
                agents.append(_vehicle(rng, pick(), s0 - rng.uniform(10, 30), "follower"))
            continue
        if not red and rng.random() < 0.75:  # cross traffic timed to meet the SDC at the junction
            r = pick()
            v = r.speed_limit * rng.uniform(0.6, 1.0)
            d = float(np.clip(v * (eta + rng.uniform(-2.5, 2.5)), 3, r.entry - 1))
            agents.append(_vehicle(rng, r, r.entry - d, "cross"))
            if rng.random() < 0.4:
                agents.append(_vehicle(rng, pick(), r.entry - d - rng.uniform(12, 35), "cross"))
        if rng.random() < 0.5:  # already through the junction, driving away
            r = pick()
            agents.append(_vehicle(rng, r, r.entry + rng.uniform(25, 60), "leaving"))
        if rng.random() < 0.3:  # further back on the approach
            r = pick()
            agents.append(_vehicle(rng, r, rng.uniform(0, r.entry - 60), "background"))
    return agents


def _priority(rng, agents: list[Agent]) -> list[Agent]:
    """Planning order: static agents and walkers, cut-ins, then lanes in random right-of-way
    order (stop and red approaches last), the vehicle in front first."""
    rank = {g: rng.random() for g in {a.route.group for a in agents}}

    def key(a: Agent):
        first = 0 if (a.walker or a.static) else 1 if a.role == "cut_in" else 2
        # stop-sign approaches and approaches at red give way to the others
        stop = a.route.stop_at is not None or (a.route.signal is not None
                                               and a.route.signal[0] != LIGHT_GO)
        return (first, stop, rank[a.route.group], -a.s0)

    return sorted(agents, key=key)


def _resampled(m: MapData, spacing: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The map's features resampled at ``spacing`` and their WOMD ``dir`` (once per map)."""
    key = ("features", spacing)
    if key not in m.cache:
        m.cache[key] = [(p, geo.next_dirs(p)) for p in
                        (geo.resample(points, spacing) for points, _ in m.features)]
    return m.cache[key]


def _edges(m: MapData) -> tuple[cKDTree, np.ndarray]:
    edges = [(p, d) for (_, t), (p, d) in zip(m.features, _resampled(m, 0.5), strict=True)
             if t in RG_ROAD_EDGE_TYPES]
    pts, dirs = (np.concatenate(a) for a in zip(*edges, strict=True))
    return cKDTree(pts), np.concatenate([pts, dirs], 1)


def offroad_steps(edges: tuple[cKDTree, np.ndarray], agent: Agent) -> np.ndarray:
    """Steps at which a box corner lies on the outer (right) side of the nearest edge point."""
    tree, table = edges
    corners = ag.box_corners(agent.xy, agent.yaw, agent.length, agent.width).reshape(-1, 2)
    _, idx = tree.query(corners)
    d, rel = table[idx, 2:], corners - table[idx, :2]
    cross = d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0]  # > 0: left of the edge (inside)
    return (cross < 0).reshape(-1, 4).any(1) & agent.valid


def _stage(rng, cast: list[Agent], edges) -> list[Agent] | None:
    planned: list[Agent] = []
    ag.pose_standing([a for a in cast if a.static])  # they ignore the others: all at once
    for agent in _priority(rng, cast):
        plan(agent, planned)
        if not agent.valid.any():
            continue
        if collides_any(agent, planned):
            if agent.is_sdc:
                return None
            continue
        planned.append(agent)
    sdc = next((a for a in planned if a.is_sdc), None)
    ok = sdc is not None and sdc.valid.all() and not offroad_steps(edges, sdc).any()
    return planned if ok else None


def plan_scenario(rng: np.random.Generator, config: GeneratorConfig = GeneratorConfig()):
    """Draw a map and a cast and plan them: ``(map, agents)`` with ``agents[i].is_sdc`` once."""
    calibrated = config.motion == "calibrated"
    bend, skew = (ROAD_BEND, JUNCTION_SKEW) if calibrated else (1.0, 1.0)
    for _ in range(config.max_attempts):
        junction = rng.random() < config.p_intersection
        m = intersection_map(rng, skew) if junction else road_map(rng, bend)
        if calibrated:
            calibrate_map(rng, m)
        edges = _edges(m)
        for _ in range(3):
            cast = _cast_intersection(rng, m) if m.kind == "intersection" else _cast_road(rng, m)
            cast = calibrate_cast(rng, m, cast) if calibrated else cast
            planned = _stage(rng, cast, edges)
            if planned is not None:
                return m, planned
    raise RuntimeError("synthetic generator: no valid scenario after max_attempts draws")


def to_scenario(rng: np.random.Generator, m: MapData, agents: list[Agent], scenario_id: str,
                config: GeneratorConfig = GeneratorConfig()) -> Scenario:
    """Place the planned map and agents at a random global pose and pack a :class:`Scenario`."""
    caps = Capacities(max_objects=config.max_objects,
                      max_roadgraph_points=config.max_roadgraph_points)
    agents = [agents[i] for i in rng.permutation(len(agents))]
    # Like a perception log, objects are valid only within sensor range of the SDC.
    sdc_xy = next(a.xy for a in agents if a.is_sdc)
    sensor = rng.uniform(90, 130)
    dist = np.linalg.norm(np.stack([a.xy for a in agents]) - sdc_xy, axis=-1)  # [N, T]
    seen = [a.valid & (d <= sensor) for a, d in zip(agents, dist, strict=True)]
    keep = [k for k, a in enumerate(agents) if seen[k].any() or a.is_sdc]
    if len(keep) > caps.max_objects:  # keep the SDC and the objects nearest to it
        near = np.argsort(dist[keep].min(1))
        keep = [keep[k] for k in np.sort(near[: caps.max_objects])]
    agents, seen = [agents[k] for k in keep], [seen[k] for k in keep]
    n = len(agents)
    if not any(a.is_sdc for a in agents):
        raise RuntimeError("synthetic generator: SDC lost while packing objects")
    angle = rng.uniform(-np.pi, np.pi)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    origin = rng.uniform(-config.origin_range, config.origin_range, 2)
    z0 = rng.uniform(-20, 60)
    place = lambda xy: xy @ rot.T + origin

    out = empty_scenario(Capacities(max_objects=n, max_roadgraph_points=1,
                                    max_traffic_lights=min(len(m.lights),
                                                           caps.max_traffic_lights)))
    xy = np.stack([place(a.xy) for a in agents])  # [n, T, 2]
    valid = np.stack(seen)
    vel = np.gradient(xy, 0.1, axis=1)
    vel[~valid] = 0
    yaw = (np.stack([a.yaw for a in agents]) + angle + np.pi) % (2 * np.pi) - np.pi
    f32 = lambda v: np.where(valid, v, 0).astype(np.float32)
    size = lambda name: np.array([getattr(a, name) for a in agents])[:, None]
    tr = out.trajectory.replace(
        x=f32(xy[..., 0]), y=f32(xy[..., 1]), z=f32(z0 + size("height") / 2), yaw=f32(yaw),
        vel_x=f32(vel[..., 0]), vel_y=f32(vel[..., 1]), length=f32(size("length")),
        width=f32(size("width")), height=f32(size("height")), valid=valid)
    sdc = int(np.flatnonzero([a.is_sdc for a in agents])[0])
    lo = np.where(valid[..., None], xy, np.inf).min(1)  # path boxes: disjoint ones never cross
    hi = np.where(valid[..., None], xy, -np.inf).max(1)
    meets = np.all((lo <= hi[sdc]) & (hi >= lo[sdc]), axis=1)
    interacting = [i for i in np.flatnonzero(meets) if i != sdc and geo.paths_intersect(
        xy[sdc], valid[sdc], xy[i], valid[i])]
    at_now = np.linalg.norm(xy[:, CURRENT_INDEX] - xy[sdc, CURRENT_INDEX], axis=1)
    at_now = np.where(valid[:, CURRENT_INDEX] & (valid.sum(1) > 20), at_now, np.inf)
    predict = np.zeros(n, bool)
    predict[np.argsort(at_now)[:8]] = np.isfinite(np.sort(at_now)[:8])
    interest = np.zeros(n, bool)
    if interacting:  # the SDC and the interacting object closest to it
        interest[[sdc, min(interacting, key=lambda i: at_now[i])]] = True
    md = out.metadata.replace(
        id=rng.choice(np.arange(1, 10_000), n, replace=False).astype(np.int32),
        object_type=np.array([a.obj_type for a in agents], np.int32),
        is_sdc=np.arange(n) == sdc, tracks_to_predict=predict, objects_of_interest=interest,
        valid=valid.any(1))
    pts, dirs, types, ids = [], [], [], []
    base = int(rng.integers(100, 5000))
    resampled = _resampled(m, config.roadgraph_spacing)
    for k, ((_, t), (p, d)) in enumerate(zip(m.features, resampled, strict=True)):
        pts.append(place(p)), dirs.append(d @ rot.T)
        types.append(np.full(len(p), t)), ids.append(np.full(len(p), base + k))
    pts, dirs = np.concatenate(pts), np.concatenate(dirs)
    r = len(pts)
    rg = out.roadgraph.replace(
        xyz=np.concatenate([pts, np.full((r, 1), z0)], 1).astype(np.float32),
        dir=np.concatenate([dirs, np.zeros((r, 1))], 1).astype(np.float32),
        type=np.concatenate(types).astype(np.int32), id=np.concatenate(ids).astype(np.int32),
        valid=np.ones(r, bool))
    tl = out.traffic_lights
    if m.lights:  # WOMD traffic_light_state: the lane (polyline id), its stop point, states
        lights = m.lights[: caps.max_traffic_lights]
        stop_xy = place(np.stack([at for _, at, _ in lights]))
        shape = (len(lights), NUM_STEPS)
        tl = tl.replace(
            state=np.stack([states for _, _, states in lights]).astype(np.int32),
            valid=np.ones(shape, bool),
            lane_id=np.repeat([[base + k] for k, _, _ in lights], NUM_STEPS, 1).astype(np.int32),
            x=np.repeat(stop_xy[:, :1], NUM_STEPS, 1).astype(np.float32),
            y=np.repeat(stop_xy[:, 1:], NUM_STEPS, 1).astype(np.float32),
            z=np.full(shape, z0, np.float32))
    scenario = out.replace(trajectory=tr, metadata=md, roadgraph=rg, traffic_lights=tl,
                           scenario_id=encode_scenario_id(scenario_id))
    return fit_to_capacities(scenario, caps)


def generate_scenario(seed: int, index: int, split: str = "training",
                      config: GeneratorConfig = GeneratorConfig()) -> Scenario:
    """The ``index``-th synthetic scenario of ``split`` for ``seed`` (deterministic), named as
    ``plot.GENERATED_ID`` parses."""
    rng = scenario_rng(seed, index, split)
    m, agents = plan_scenario(rng, config)
    return to_scenario(rng, m, agents, f"syn{seed:x}{SPLIT_LETTERS[split]}{index:08d}", config)
