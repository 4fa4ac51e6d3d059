"""Procedural maps (a curved multi-lane road or an N-arm intersection): roadgraph features
(polylines with a WOMD type), the *routes* agents drive and pedestrian paths. Road edges are
oriented so that the road interior lies on the LEFT of the point direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from itertools import combinations

import numpy as np
from scipy.spatial import cKDTree

from igdrivsim.data.scenario import (
    DT,
    NUM_STEPS,
    RG_CROSSWALK,
    RG_LANE_BIKE,
    RG_LANE_FREEWAY,
    RG_LANE_SURFACE_STREET,
    RG_ROAD_EDGE_BOUNDARY,
    RG_ROAD_EDGE_MEDIAN,
    RG_STOP_SIGN,
)
from igdrivsim.data.synthetic import geometry as geo

BROKEN_WHITE, SOLID_WHITE, BROKEN_YELLOW = 6, 7, 9
SOLID_DOUBLE_YELLOW, PASSING_DOUBLE_YELLOW = 12, 13
ROUTE_SPACING = 1.0  # m between route samples used for planning
STOP_LINE = 4.5  # m before the junction box (behind the crosswalk) where stop signs stop cars
# WOMD TrafficSignalLaneState values written in traffic_light_state/*/state
LIGHT_STOP, LIGHT_CAUTION, LIGHT_GO = 4, 5, 6
YELLOW_S, ALL_RED_S = 3.0, 1.5  # yellow and all-red times of a signal cycle (s)


@dataclass
class Route:
    """A path an agent can drive: ``points [K, 2]`` at ~1 m spacing; ``group`` names the lane
    it starts on, ``kind`` its type ("lane", "change", "merge", "straight", "left", ...)."""

    points: np.ndarray
    group: int
    kind: str = "lane"
    speed_limit: float = 13.0
    entry: float = 0.0  # intersection routes: arc length where the route enters the junction
    stop_at: float | None = None  # arc length of a stop line (stop sign) on the route
    signal: np.ndarray | None = None  # light state per step (LIGHT_*) at ``signal_at``
    signal_at: float | None = None  # arc length of the signal's stop line on the route
    lane: int = 0  # intersection approaches: lane index from the kerb (0: kerb lane)

    @cached_property
    def s(self) -> np.ndarray:
        """Arc length at each point."""
        return geo.arc_length(self.points)

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(lo, hi)`` of the points."""
        return self.points.min(0), self.points.max(0)

    @cached_property
    def yaw(self) -> np.ndarray:
        """Unwrapped heading at each point."""
        return geo.unwrapped_yaw(self.points)

    @cached_property
    def smooth_curvature(self) -> np.ndarray:
        """|curvature| averaged over 7 points (the planner's curve speed limit)."""
        # geo.curvature(points) from the cached heading and arc length (the same arithmetic)
        kappa = np.abs(np.gradient(self.yaw, self.s) if len(self.points) >= 3
                       else np.zeros(len(self.points)))
        return np.convolve(np.pad(kappa, 3, mode="edge"), np.ones(7) / 7, "valid")

    @cached_property
    def tree(self) -> cKDTree:
        """A k-d tree of the points (nearest route point of a position)."""
        return cKDTree(self.points)

    @cached_property
    def tangents(self) -> np.ndarray:
        """Unit tangent at each point."""
        return geo.tangents(self.points)


@dataclass
class MapData:
    features: list[tuple[np.ndarray, int]] = field(default_factory=list)  # (points [N,2], type)
    routes: list[Route] = field(default_factory=list)
    walk_paths: list[np.ndarray] = field(default_factory=list)  # pedestrian crossings [2, 2]
    walk_steps: list[np.ndarray | None] = field(default_factory=list)  # signalised: steps to go
    sidewalks: list[np.ndarray] = field(default_factory=list)  # paths beside the road [N, 2]
    kind: str = "road"
    ref: np.ndarray | None = None  # road maps: the centre line the lanes are offsets of
    lanes: dict[int, tuple[float, int]] = field(default_factory=dict)  # group -> (offset, dir)
    parking: list[Route] = field(default_factory=list)  # kerbside strips with parked cars
    bike_routes: list[Route] = field(default_factory=list)  # bike lanes (cyclists)
    no_parking: list[np.ndarray] = field(default_factory=list)  # segments [2, 2] kept clear
    stop_arms: set[int] = field(default_factory=set)  # intersection arms with stop signs
    dropped: set[int] = field(default_factory=set)  # road lanes that end (their traffic merges)
    # signalised lanes: (feature index of the lane polyline, stop point [2], states [T])
    lights: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    # road maps with a signalised crosswalk: (ref index, vehicle states [T], pedestrian steps)
    crossing: tuple[int, np.ndarray, np.ndarray] | None = None
    cache: dict = field(default_factory=dict, repr=False)  # the generator's per-map results

    def add(self, points: np.ndarray, rg_type: int) -> int:
        """Append a feature; its index (the roadgraph polyline id is derived from it)."""
        self.features.append((np.asarray(points, float), int(rg_type)))
        return len(self.features) - 1


def signal_states(rng: np.random.Generator, phases: int = 2,
                  green: tuple[float, float] = (10.0, 30.0)) -> np.ndarray:
    """Light states ``[phases, T]`` of a fixed-time cycle seen from a random point of it."""
    greens = rng.uniform(*green, phases)
    slots = greens + YELLOW_S + ALL_RED_S
    cycle = slots.sum()
    t = (rng.uniform(0, cycle) + np.arange(NUM_STEPS) * DT) % cycle
    out = np.full((phases, NUM_STEPS), LIGHT_STOP, np.int32)
    start = 0.0
    for p in range(phases):
        u = t - start
        out[p, (u >= 0) & (u < greens[p])] = LIGHT_GO
        out[p, (u >= greens[p]) & (u < greens[p] + YELLOW_S)] = LIGHT_CAUTION
        start += slots[p]
    return out


def attach_crossing_signal(m: MapData, route: Route) -> None:
    """Road maps: give ``route`` the signal of the map's signalised crosswalk (if it crosses it)."""
    if m.crossing is None:
        return
    i, states, _ = m.crossing
    t = geo.tangents(m.ref)[i]
    rel = route.points - m.ref[i]
    along, across = rel @ t, rel @ np.array([-t[1], t[0]])
    near = np.abs(across) < 20
    if not near.any() or np.abs(along[near]).min() > 1.5:
        return
    k = np.flatnonzero(near)[np.argmin(np.abs(along[near]))]
    route.signal, route.signal_at = states, float(route.s[k]) - STOP_LINE


def lane_change_route(m: MapData, src: int, dst: int, start: float, span: float) -> Route:
    """Road maps: drive lane ``src``, moving to lane ``dst`` over ``[start, start + span]`` m."""
    (d0, direction), (d1, _) = m.lanes[src], m.lanes[dst]
    s = geo.arc_length(m.ref)
    s_dir = s if direction > 0 else s[-1] - s
    u = np.clip((s_dir - start) / span, 0, 1)
    path = geo.offset(m.ref, d0 + (d1 - d0) * u * u * (3 - 2 * u))
    limit = next(r.speed_limit for r in m.routes if r.group == src)
    route = _route(path[::direction], src, "change", limit)
    attach_crossing_signal(m, route)
    return route


def _route(points: np.ndarray, group: int, kind: str, limit: float) -> Route:
    return Route(geo.resample(points, ROUTE_SPACING), group, kind, limit)


def _crosswalk(m: MapData, centre, along, half_len: float, half_width: float) -> None:
    """A crosswalk polygon (closed) and its pedestrian path, ``along`` the walking direction."""
    along = np.asarray(along, float) / np.linalg.norm(along)
    side = np.array([-along[1], along[0]])
    c = np.asarray(centre, float)
    a, b = half_len * along, half_width * side
    poly = np.array([c - a - b, c + a - b, c + a + b, c - a + b])
    m.add(np.concatenate([poly, poly[:1]]), RG_CROSSWALK)
    m.walk_paths.append(np.stack([c - (half_len + 2.5) * along, c + (half_len + 2.5) * along]))
    m.walk_steps.append(None)


def _reference_curve(rng: np.random.Generator, length: float, bend: float = 1.0) -> np.ndarray:
    """A smooth centre line: straight pieces and bends (radius >= 35 m / ``bend``)."""
    ds = 0.5
    kappa = np.zeros(int(length / ds) + 1)
    s = 0.0
    while s < length:
        piece = rng.uniform(40, 110)
        if rng.random() < 0.55:
            radius = rng.uniform(35, 140)
            angle = rng.uniform(np.pi / 6, np.pi / 1.8)
            piece = min(radius * angle, piece + 60)
            i0, i1 = int(s / ds), int(min(s + piece, length) / ds)
            kappa[i0:i1] = rng.choice([-1, 1]) / radius
        s += piece
    win = int(25 / ds)  # ~25 m transitions
    kappa = np.convolve(np.pad(kappa, win, mode="edge"), np.ones(win) / win, "same")[win:-win]
    yaw = np.cumsum(kappa * bend) * ds
    pts = np.stack([np.cos(yaw), np.sin(yaw)], 1).cumsum(0) * ds
    return geo.resample(pts - pts[0], 1.0)


def road_map(rng: np.random.Generator, bend: float = 1.0) -> MapData:
    """A curved road (curvature times ``bend``), 1-3 lanes each way (or one-way), maybe divided,
    with parking, bike lanes, side streets, a lane drop and a (signalised) crosswalk."""
    ref = _reference_curve(rng, rng.uniform(340, 400), bend)
    m = MapData(kind="road", ref=ref)
    n_fwd = int(rng.choice([1, 2, 3], p=[0.05, 0.4, 0.55]))
    n_back = int(rng.choice([0, 1, 2, 3], p=[0.05, 0.2, 0.45, 0.3]))
    w = rng.uniform(3.4, 3.9)
    median = rng.uniform(1.0, 3.0) if n_back and rng.random() < 0.3 else 0.0
    centre_lane = bool(n_back and not median and rng.random() < 0.6)  # two-way left-turn lane
    shoulder = rng.uniform(0.3, 1.2)
    freeway = median > 0 and rng.random() < 0.5
    lane_type = RG_LANE_FREEWAY if freeway else RG_LANE_SURFACE_STREET
    limit = rng.uniform(13, 17) if freeway else rng.uniform(9, 14)
    half_m = w / 2 if centre_lane else median / 2
    fwd_off = [-(j + 0.5) * w - half_m for j in range(n_fwd)]
    back_off = [(j + 0.5) * w + half_m for j in range(n_back)]
    park_r = rng.uniform(2.3, 2.7) if rng.random() < 0.7 else 0.0
    park_l = rng.uniform(2.3, 2.7) if n_back and rng.random() < 0.6 else 0.0
    bike = rng.uniform(1.5, 1.8) if rng.random() < 0.5 else 0.0  # bike lanes on both kerbs
    bike_l = bike if n_back else 0.0
    s_ref = geo.arc_length(ref)
    smooth = lambda u: np.clip(u, 0, 1) ** 2 * (3 - 2 * np.clip(u, 0, 1))
    # Lane drop: the rightmost lane tapers away over [drop - taper, drop]; its traffic merges.
    drop = (rng.uniform(170, 240) if n_fwd >= 2 and not park_r and not bike
            and rng.random() < 0.5 else None)
    taper = rng.uniform(50, 80)
    before_drop = s_ref < (drop - taper if drop else np.inf)
    # a crosswalk somewhere in the middle third, half of them signalised
    cross_i = (int(np.searchsorted(s_ref, rng.uniform(0.3, 0.6) * s_ref[-1]))
               if rng.random() < 0.7 else None)
    if cross_i is not None and rng.random() < 0.6:
        states = signal_states(rng, 2, green=(8.0, 25.0))
        m.crossing = (cross_i, states[0], np.flatnonzero(states[0] == LIGHT_STOP))
    group = 0
    for offs, direction in ((fwd_off, 1), (back_off, -1)):
        for j, lane in enumerate(geo.offset(ref, d)[::direction] for d in offs):
            m.lanes[group + j] = (offs[j], direction)
            lights = m.crossing is not None
            if drop and direction > 0 and j == len(offs) - 1:
                k = m.add(lane[before_drop], lane_type)
                lights = lights and cross_i + 6 < before_drop.sum()
                start = drop - taper - rng.uniform(25, 70)
                merge = offs[j] + (offs[j - 1] - offs[j]) * smooth(
                    (s_ref - start) / rng.uniform(25, 45))
                m.routes.append(_route(geo.offset(ref, merge), group + j, "merge", limit))
                m.dropped.add(group + j)
            else:
                k = m.add(lane, lane_type)
                m.routes.append(_route(lane, group + j, "lane", limit))
            if lights:  # the stop line STOP_LINE m before the crosswalk
                at = geo.offset(ref, offs[j])[cross_i - direction * int(STOP_LINE + 1)]
                m.lights.append((k, at, m.crossing[1]))
        for j in range(len(offs) - 1):
            line = geo.offset(ref, (offs[j] + offs[j + 1]) / 2)
            if drop and direction > 0 and j == len(offs) - 2:
                line = line[before_drop]
            m.add(line[::direction], BROKEN_WHITE)
        group += len(offs)
    right = -(n_fwd * w + half_m + bike + park_r + shoulder)
    if drop:
        right = right + w * smooth((s_ref - (drop - taper)) / taper)
    left = (n_back * w + half_m + bike_l + park_l if n_back else 0.0) + shoulder
    right = np.broadcast_to(right, s_ref.shape)
    # the kerb sides, right then left: (offset sign, traffic lanes, bike lane, parking strip);
    # kerb_line: the line d m out on a side, in that side's driving direction
    kerbs = ((-1, n_fwd, bike, park_r), (1, n_back, bike_l, park_l))
    kerb_line = lambda sign, d: geo.offset(ref, sign * d)[::-sign]
    # side streets (T junctions), on straight stretches away from the crosswalk and each other
    kappa = np.abs(geo.curvature(ref))
    taken = [cross_i] if cross_i is not None else []
    sides = {}
    for side, p in (("right", 0.0 if drop else 0.85), ("left", 0.55 if n_back else 0.0)):
        if rng.random() >= p:
            continue
        for at in rng.uniform(0.25, 0.75, 12) * s_ref[-1]:
            i = int(np.searchsorted(s_ref, at))
            if kappa[max(i - 30, 0): i + 30].max() < 1 / 90 and all(abs(i - j) > 40
                                                                      for j in taken):
                taken.append(i)
                sides[side] = i
                break
    if "right" in sides:
        _side_street(rng, m, ref, sides["right"], right, fwd_off,
                     back_off if not median else [], w, limit, 100)
    else:
        m.add(geo.offset(ref, right), RG_ROAD_EDGE_BOUNDARY)
    if "left" in sides:  # the same construction seen from the other direction
        _side_street(rng, m, ref[::-1], len(ref) - 1 - sides["left"], np.full(len(ref), -left),
                     [-o for o in back_off], [-o for o in fwd_off] if not median else [], w,
                     limit, 110)
    else:
        m.add(geo.offset(ref, left)[::-1], RG_ROAD_EDGE_BOUNDARY)
    if median > 0:
        m.add(geo.offset(ref, -half_m)[::-1], RG_ROAD_EDGE_MEDIAN)
        m.add(geo.offset(ref, half_m), RG_ROAD_EDGE_MEDIAN)
    elif centre_lane:
        m.add(geo.offset(ref, 0.0), RG_LANE_SURFACE_STREET)
        m.add(geo.offset(ref, -half_m), BROKEN_YELLOW)
        m.add(geo.offset(ref, half_m)[::-1], BROKEN_YELLOW)
    elif n_back:
        m.add(geo.offset(ref, 0.0), int(rng.choice(
            [SOLID_DOUBLE_YELLOW, BROKEN_YELLOW, PASSING_DOUBLE_YELLOW], p=[0.6, 0.25, 0.15])))
    for sign, n, bk, park in kerbs:
        if park or bk:  # a solid white line beside the outer traffic lane
            m.add(kerb_line(sign, n * w + half_m), SOLID_WHITE)
    for k, (sign, n, bk, park) in enumerate(kerbs):
        if park:  # parking strips: routes (never driven) where parked cars stand
            m.parking.append(_route(kerb_line(sign, n * w + half_m + bk + park / 2), -2 - k,
                                    "parking", 0.0))
        if bk:  # bike lanes (WOMD lane type 3), ridden by cyclists
            m.bike_routes.append(_route(kerb_line(sign, n * w + half_m + bk / 2), -4 - k, "bike",
                                        6.0))
            m.add(m.bike_routes[-1].points, RG_LANE_BIKE)
    m.sidewalks += [geo.offset(ref, side) for side in (right - 2.0, left + 2.0)]  # 2 m outside
    if cross_i is not None:
        t = geo.tangents(ref)[cross_i]
        normal = np.array([-t[1], t[0]])
        mid = ref[cross_i] + normal * (left + right[cross_i]) / 2
        _crosswalk(m, mid, normal, (left - right[cross_i]) / 2, 1.6)
        if m.crossing is not None:
            m.walk_steps[-1] = m.crossing[2]
    for route in m.routes + m.bike_routes:
        attach_crossing_signal(m, route)
    return m


def _side_street(rng, m: MapData, ref: np.ndarray, i: int, right: np.ndarray, fwd_off: list,
                 back_off: list, w: float, limit: float, group: int) -> None:
    """A two-lane side street joining the road's right kerb at ``ref[i]``: edges with rounded
    corners, lanes, and turn routes (left turns only across ``back_off`` lanes)."""
    t = geo.tangents(ref)[i]
    d = -np.array([-t[1], t[0]])  # outwards, away from the road
    kerb = ref[i] - d * right[i]
    hs, c, far = w, rng.uniform(6.0, 9.0), rng.uniform(50, 70)
    edge = geo.offset(ref, right)
    lo, hi = i - int(hs + c), i + int(hs + c) + 1
    up = geo.concat(edge[:lo], geo.bezier_cubic(edge[lo - 1], t * c * 0.55,
                                                 kerb - t * hs + d * c, d * c * 0.55, 16),
                    geo.resample(np.stack([kerb - t * hs + d * c, kerb - t * hs + d * far]), 1.0))
    down = geo.concat(geo.resample(np.stack([kerb + t * hs + d * far, kerb + t * hs + d * c]),
                                   1.0),
                      geo.bezier_cubic(kerb + t * hs + d * c, -d * c * 0.55, edge[hi], t * c * 0.55,
                                       16), edge[hi:])
    m.add(up, RG_ROAD_EDGE_BOUNDARY)
    m.add(down, RG_ROAD_EDGE_BOUNDARY)
    m.add(np.stack([kerb + d * (c + 1), kerb + d * far]), SOLID_DOUBLE_YELLOW)
    lane_in = geo.resample(np.stack([kerb + t * hs / 2 + d * far, kerb + t * hs / 2 + d]), 1.0)
    lane_out = geo.resample(np.stack([kerb - t * hs / 2 + d, kerb - t * hs / 2 + d * far]), 1.0)
    m.add(lane_in, RG_LANE_SURFACE_STREET)
    m.add(lane_out, RG_LANE_SURFACE_STREET)
    m.no_parking.append(np.stack([kerb - t * (hs + c + 3), kerb + t * (hs + c + 3)]))
    fwd = geo.offset(ref, fwd_off[-1])  # the kerb lane (forward)
    joins = [(fwd[: i - 14], lane_out, "right"), (lane_in, fwd[i + 14:], "right")]
    if back_off:
        back = geo.offset(ref, back_off[0])[::-1]  # the innermost oncoming lane
        n = len(back)
        joins += [(back[: n - i - 16], lane_out, "left"), (lane_in, back[n - i + 16:], "left")]
    for a, b, kind in joins:
        ta, tb = geo.tangents(a)[-1], geo.tangents(b)[0]
        k = 0.4 * np.linalg.norm(b[0] - a[-1])
        conn = geo.bezier_cubic(a[-1], ta * k, b[0], tb * k, 30)
        m.add(conn, RG_LANE_SURFACE_STREET)
        m.routes.append(_route(geo.concat(a, conn, b), group, kind, limit * 0.8))
        group += 1


def intersection_map(rng: np.random.Generator, skew: float = 1.0) -> MapData:
    """A 3- or 4-arm intersection (1-3 lanes per direction, arms up to ``0.2 skew`` rad off right
    angles; crosswalks, parking) with no control, stop signs or two-phase traffic lights."""
    m = MapData(kind="intersection")
    n_arms = 3 if rng.random() < 0.3 else 4
    angles = np.arange(4) * np.pi / 2 + skew * rng.uniform(-0.2, 0.2, 4)
    if n_arms == 3:
        angles = np.delete(angles, rng.integers(4))
    u = np.stack([np.cos(angles), np.sin(angles)], 1)
    nrm = np.stack([-u[:, 1], u[:, 0]], 1)
    n_in = rng.choice([1, 2, 2, 2, 3, 3], n_arms)
    n_out = np.where(rng.random(n_arms) < 0.7, n_in,
                     np.clip(n_in + rng.choice([-1, 1], n_arms), 1, 3))
    w = rng.uniform(3.3, 3.8)
    corner = rng.uniform(5.0, 10.0)
    length = rng.uniform(140, 170)
    limit = rng.uniform(9, 13)
    park = np.where(rng.random((n_arms, 2)) < 0.7, rng.uniform(2.3, 2.7, (n_arms, 2)), 0.0)
    side_in, side_out = n_in * w + park[:, 0], n_out * w + park[:, 1]  # kerb offsets
    control = rng.choice(["none", "two_way", "all_way", "signal"], p=[0.1, 0.12, 0.08, 0.7])
    if control == "all_way":
        m.stop_arms = set(range(n_arms))
    elif control == "two_way":
        parity = int(rng.integers(2))
        m.stop_arms = {a for a in range(n_arms) if a % 2 == parity} or {0}
    phase = np.arange(n_arms) % 2
    if n_arms == 3:  # the two most nearly opposite arms share a phase
        a, b = min(combinations(range(3), 2), key=lambda p: float(u[p[0]] @ u[p[1]]))
        phase = np.array([0 if k in (a, b) else 1 for k in range(3)])
    states = signal_states(rng, 2) if control == "signal" else None
    gaps = np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi]))
    half_width = np.maximum(side_in, side_out)
    r = float(half_width.max() / np.sin(min(gaps.min(), np.pi / 2)) + corner * 0.7 + 1.0)
    along = lambda a, d: lambda s: u[a] * s + nrm[a] * d
    line = lambda a, d, s0, s1: np.stack([along(a, d)(s) for s in np.linspace(s0, s1, 2)])
    ins, outs = {}, {}
    for a in range(n_arms):
        for j in range(n_in[a]):
            ins[a, j] = geo.resample(line(a, (j + 0.5) * w, length, r), 1.0)
            k = m.add(ins[a, j], RG_LANE_SURFACE_STREET)
            if states is not None:
                m.lights.append((k, along(a, (j + 0.5) * w)(r + STOP_LINE), states[phase[a]]))
        for j in range(n_out[a]):
            outs[a, j] = geo.resample(line(a, -(j + 0.5) * w, r, length), 1.0)
            m.add(outs[a, j], RG_LANE_SURFACE_STREET)
        for j in range(1, n_in[a]):
            m.add(geo.resample(line(a, j * w, length, r), 1.0), BROKEN_WHITE)
        for j in range(1, n_out[a]):
            m.add(geo.resample(line(a, -j * w, r, length), 1.0), BROKEN_WHITE)
        m.add(geo.resample(line(a, 0.0, r, length), 1.0), SOLID_DOUBLE_YELLOW)
        if park[a, 0]:  # kerbside parking from 8 m behind the crosswalk outwards
            m.parking.append(_route(line(a, n_in[a] * w + park[a, 0] / 2, length, r + 8), -2,
                                    "parking", 0.0))
            m.add(geo.resample(line(a, n_in[a] * w, length, r + 8), 1.0), SOLID_WHITE)
        if park[a, 1]:
            m.parking.append(_route(line(a, -(n_out[a] * w + park[a, 1] / 2), r + 8, length),
                                    -3, "parking", 0.0))
            m.add(geo.resample(line(a, -n_out[a] * w, r + 8, length), 1.0), SOLID_WHITE)
        m.sidewalks.append(line(a, side_in[a] + 2.0, length, r + 4))
        m.sidewalks.append(line(a, -(side_out[a] + 2.0), r + 4, length))
        if a in m.stop_arms:  # WOMD stop signs are single points beside the stop line
            m.add(along(a, side_in[a] + 0.8)(r + STOP_LINE)[None], RG_STOP_SIGN)
        _crosswalk(m, u[a] * (r + 2.0) + nrm[a] * (side_in[a] - side_out[a]) / 2, nrm[a],
                   (side_in[a] + side_out[a]) / 2, 1.5)
        if states is not None:  # pedestrians cross while this arm's traffic has red
            m.walk_steps[-1] = np.flatnonzero(states[phase[a]] == LIGHT_STOP)
    # Corners: arm a's left side (inwards) -> rounded corner -> next arm's right side (outwards).
    for a in range(n_arms):
        b = (a + 1) % n_arms
        p0, p1 = along(a, side_in[a])(r), along(b, -side_out[b])(r)
        c = 0.39 * np.linalg.norm(p1 - p0)
        bend = geo.bezier_cubic(p0, -u[a] * c, p1, u[b] * c, 40)
        edge = geo.concat(line(a, side_in[a], length, r), bend, line(b, -side_out[b], r, length))
        m.add(geo.resample(edge, 0.5), RG_ROAD_EDGE_BOUNDARY)
    # Routes: approach lane + connector + exit lane, one group per approach lane.
    group = 0
    for a in range(n_arms):
        for j in range(n_in[a]):
            for b in range(n_arms):
                if b == a:
                    continue
                cross = -u[a, 0] * u[b, 1] + u[a, 1] * u[b, 0]
                turn = np.arctan2(cross, np.dot(-u[a], u[b]))
                if abs(turn) < np.pi / 5:
                    kind, k = "straight", min(j, n_out[b] - 1)
                elif j == (0 if turn < 0 else n_in[a] - 1):  # turns from the outer lanes only
                    kind, k = ("right", 0) if turn < 0 else ("left", n_out[b] - 1)
                else:
                    continue
                start, end = ins[a, j][-1], outs[b, k][0]
                c = 0.4 * np.linalg.norm(end - start)
                conn = geo.bezier_cubic(start, -u[a] * c, end, u[b] * c, 30)
                m.add(conn, RG_LANE_SURFACE_STREET)
                route = _route(geo.concat(ins[a, j], conn, outs[b, k]), group, kind, limit)
                route.entry = float(geo.arc_length(ins[a, j])[-1])
                route.lane = j
                if a in m.stop_arms:
                    route.stop_at = route.entry - STOP_LINE
                if states is not None:
                    route.signal, route.signal_at = states[phase[a]], route.entry - STOP_LINE
                m.routes.append(route)
            group += 1
    return m
