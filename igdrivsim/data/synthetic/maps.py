"""Procedural road maps: a curved multi-lane road and an N-arm intersection.

A map is a list of roadgraph features (polylines with a WOMD type) plus the driving *routes* the
agents follow (lane centres, lane changes, turns through the intersection) and pedestrian paths.
Road edges are oriented so that the road interior lies on the LEFT of the point direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from igdrivsim.data.scenario import (
    RG_CROSSWALK,
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


@dataclass
class Route:
    """A path an agent can drive: ``points [K, 2]`` at ~1 m spacing.

    ``group`` names the lane the route starts on (routes of one group share their beginning);
    ``kind`` is "lane", "change", "merge", "straight", "left" or "right".
    """

    points: np.ndarray
    group: int
    kind: str = "lane"
    speed_limit: float = 13.0
    entry: float = 0.0  # intersection routes: arc length where the route enters the junction
    stop_at: float | None = None  # arc length of a stop line (stop sign) on the route

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


@dataclass
class MapData:
    features: list[tuple[np.ndarray, int]] = field(default_factory=list)  # (points [N,2], type)
    routes: list[Route] = field(default_factory=list)
    walk_paths: list[np.ndarray] = field(default_factory=list)  # pedestrian crossings [2, 2]
    sidewalks: list[np.ndarray] = field(default_factory=list)  # paths beside the road [N, 2]
    kind: str = "road"
    ref: np.ndarray | None = None  # road maps: the centre line the lanes are offsets of
    lanes: dict[int, tuple[float, int]] = field(default_factory=dict)  # group -> (offset, dir)
    parking: list[Route] = field(default_factory=list)  # kerbside strips with parked cars
    stop_arms: set[int] = field(default_factory=set)  # intersection arms with stop signs
    dropped: set[int] = field(default_factory=set)  # road lanes that end (their traffic merges)

    def add(self, points: np.ndarray, rg_type: int) -> None:
        self.features.append((np.asarray(points, float), int(rg_type)))


def lane_change_route(m: MapData, src: int, dst: int, start: float, span: float) -> Route:
    """Road maps: drive lane ``src`` and move smoothly to lane ``dst`` over ``[start,
    start + span]`` metres (measured along the driving direction)."""
    (d0, direction), (d1, _) = m.lanes[src], m.lanes[dst]
    s = geo.arc_length(m.ref)
    s_dir = s if direction > 0 else s[-1] - s
    u = np.clip((s_dir - start) / span, 0, 1)
    path = geo.offset(m.ref, d0 + (d1 - d0) * u * u * (3 - 2 * u))
    limit = next(r.speed_limit for r in m.routes if r.group == src)
    return _route(path if direction > 0 else path[::-1], src, "change", limit)


def _route(points: np.ndarray, group: int, kind: str, limit: float) -> Route:
    return Route(geo.resample(points, ROUTE_SPACING), group, kind, limit)


def _crosswalk(m: MapData, centre, along, half_len: float, half_width: float) -> None:
    """A crosswalk polygon (closed) and its pedestrian path, ``along`` the walking direction."""
    along = np.asarray(along, float) / np.linalg.norm(along)
    side = np.array([-along[1], along[0]])
    c = np.asarray(centre, float)
    poly = np.array([c - half_len * along - half_width * side, c + half_len * along - half_width
                     * side, c + half_len * along + half_width * side,
                     c - half_len * along + half_width * side])
    m.add(np.concatenate([poly, poly[:1]]), RG_CROSSWALK)
    m.walk_paths.append(np.stack([c - (half_len + 2.5) * along, c + (half_len + 2.5) * along]))


def _reference_curve(rng: np.random.Generator, length: float) -> np.ndarray:
    """A smooth centre line: straight pieces and bends (radius >= 35 m), clothoid-like."""
    ds = 0.5
    n = int(length / ds) + 1
    kappa = np.zeros(n)
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
    yaw = np.cumsum(kappa) * ds
    pts = np.stack([np.cos(yaw), np.sin(yaw)], 1).cumsum(0) * ds
    return geo.resample(pts - pts[0], 1.0)


def road_map(rng: np.random.Generator) -> MapData:
    """A curved road, 1-3 lanes each way (or one-way), sometimes divided, parking strips, a lane
    drop (the rightmost lane ends and its traffic merges), maybe a crosswalk."""
    ref = _reference_curve(rng, rng.uniform(340, 400))
    m = MapData(kind="road", ref=ref)
    n_fwd = int(rng.choice([1, 2, 2, 3]))
    n_back = int(rng.choice([0, 1, 2], p=[0.15, 0.45, 0.4]))
    w = rng.uniform(3.4, 3.9)
    median = rng.uniform(1.0, 3.0) if n_back and rng.random() < 0.3 else 0.0
    shoulder = rng.uniform(0.3, 1.2)
    freeway = median > 0 and rng.random() < 0.5
    lane_type = RG_LANE_FREEWAY if freeway else RG_LANE_SURFACE_STREET
    limit = rng.uniform(13, 17) if freeway else rng.uniform(9, 14)
    half_m = median / 2
    rev = lambda p: p[::-1]  # noqa: E731
    fwd_off = [-(j + 0.5) * w - half_m for j in range(n_fwd)]
    back_off = [(j + 0.5) * w + half_m for j in range(n_back)]
    park_r = rng.uniform(2.3, 2.7) if rng.random() < 0.45 else 0.0
    park_l = rng.uniform(2.3, 2.7) if n_back and rng.random() < 0.35 else 0.0
    s_ref = geo.arc_length(ref)
    smooth = lambda u: np.clip(u, 0, 1) ** 2 * (3 - 2 * np.clip(u, 0, 1))  # noqa: E731
    # Lane drop: the rightmost lane tapers away over [drop - taper, drop]; its traffic merges.
    drop = rng.uniform(170, 240) if n_fwd >= 2 and not park_r and rng.random() < 0.5 else None
    taper = rng.uniform(50, 80)
    before_drop = s_ref < (drop - taper if drop else np.inf)
    group = 0
    for offs, direction in ((fwd_off, 1), (back_off, -1)):
        lanes = [geo.offset(ref, d) for d in offs]
        lanes = [lane if direction > 0 else rev(lane) for lane in lanes]
        for j, lane in enumerate(lanes):
            m.lanes[group + j] = (offs[j], direction)
            if drop and direction > 0 and j == len(offs) - 1:
                m.add(lane[before_drop], lane_type)
                start = drop - taper - rng.uniform(25, 70)
                merge = offs[j] + (offs[j - 1] - offs[j]) * smooth(
                    (s_ref - start) / rng.uniform(25, 45))
                m.routes.append(_route(geo.offset(ref, merge), group + j, "merge", limit))
                m.dropped.add(group + j)
                continue
            m.add(lane, lane_type)
            m.routes.append(_route(lane, group + j, "lane", limit))
        for j in range(len(offs) - 1):
            line = geo.offset(ref, (offs[j] + offs[j + 1]) / 2)
            if drop and direction > 0 and j == len(offs) - 2:
                line = line[before_drop]
            m.add(line if direction > 0 else rev(line), BROKEN_WHITE)
        group += len(offs)
    right = -(n_fwd * w + half_m + park_r + shoulder)
    if drop:
        right = right + w * smooth((s_ref - (drop - taper)) / taper)
    left = (n_back * w + half_m + park_l if n_back else 0.0) + shoulder
    right = np.broadcast_to(right, s_ref.shape)
    if park_r:  # parking strips: routes (never driven) where parked cars stand
        m.parking.append(_route(geo.offset(ref, -(n_fwd * w + half_m + park_r / 2)), -2,
                                "parking", 0.0))
    if park_l:
        m.parking.append(_route(geo.offset(ref, n_back * w + half_m + park_l / 2)[::-1], -3,
                                "parking", 0.0))
    m.add(geo.offset(ref, right), RG_ROAD_EDGE_BOUNDARY)
    m.add(rev(geo.offset(ref, left)), RG_ROAD_EDGE_BOUNDARY)
    if median > 0:
        m.add(rev(geo.offset(ref, -half_m)), RG_ROAD_EDGE_MEDIAN)
        m.add(geo.offset(ref, half_m), RG_ROAD_EDGE_MEDIAN)
    elif n_back:
        m.add(geo.offset(ref, 0.0), int(rng.choice(
            [SOLID_DOUBLE_YELLOW, BROKEN_YELLOW, PASSING_DOUBLE_YELLOW], p=[0.6, 0.25, 0.15])))
    if park_r:  # a solid white line separates the parking strip from the traffic lane
        m.add(geo.offset(ref, -(n_fwd * w + half_m)), SOLID_WHITE)
    if park_l:
        m.add(geo.offset(ref, n_back * w + half_m)[::-1], SOLID_WHITE)
    for side in (right - 2.0, left + 2.0):  # sidewalks, 2 m outside the road edges
        m.sidewalks.append(geo.offset(ref, side))
    if rng.random() < 0.6:  # a crosswalk somewhere in the middle third
        i = int(np.searchsorted(s_ref, rng.uniform(0.3, 0.6) * s_ref[-1]))
        t = geo.tangents(ref)[i]
        normal = np.array([-t[1], t[0]])
        mid = ref[i] + normal * (left + right[i]) / 2
        _crosswalk(m, mid, normal, (left - right[i]) / 2, 1.6)
    return m


def intersection_map(rng: np.random.Generator) -> MapData:
    """A 3- or 4-arm intersection of two-way roads with turn lanes and crosswalks."""
    m = MapData(kind="intersection")
    n_arms = 3 if rng.random() < 0.3 else 4
    angles = np.arange(4) * np.pi / 2 + rng.uniform(-0.2, 0.2, 4)
    if n_arms == 3:
        angles = np.delete(angles, rng.integers(4))
    u = np.stack([np.cos(angles), np.sin(angles)], 1)
    nrm = np.stack([-u[:, 1], u[:, 0]], 1)
    n_in = rng.choice([1, 1, 2], n_arms)
    n_out = np.where(rng.random(n_arms) < 0.7, n_in, 3 - n_in)
    w = rng.uniform(3.3, 3.8)
    corner = rng.uniform(5.0, 10.0)
    length = rng.uniform(140, 170)
    limit = rng.uniform(9, 13)
    control = rng.choice(["none", "two_way", "all_way"], p=[0.35, 0.4, 0.25])
    if control == "all_way":
        stop_arms = set(range(n_arms))
    elif control == "two_way":
        parity = int(rng.integers(2))
        stop_arms = {a for a in range(n_arms) if a % 2 == parity} or {0}
    else:
        stop_arms = set()
    m.stop_arms = stop_arms
    gaps = np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi]))
    half_width = np.maximum(n_in, n_out) * w
    r = float(half_width.max() / np.sin(min(gaps.min(), np.pi / 2)) + corner * 0.7 + 1.0)
    along = lambda a, d: lambda s: u[a] * s + nrm[a] * d  # noqa: E731
    line = lambda a, d, s0, s1: np.stack([along(a, d)(s) for s in np.linspace(s0, s1, 2)])  # noqa: E731
    ins, outs = {}, {}
    for a in range(n_arms):
        for j in range(n_in[a]):
            ins[a, j] = geo.resample(line(a, (j + 0.5) * w, length, r), 1.0)
            m.add(ins[a, j], RG_LANE_SURFACE_STREET)
        for j in range(n_out[a]):
            outs[a, j] = geo.resample(line(a, -(j + 0.5) * w, r, length), 1.0)
            m.add(outs[a, j], RG_LANE_SURFACE_STREET)
        for j in range(1, n_in[a]):
            m.add(geo.resample(line(a, j * w, length, r), 1.0), BROKEN_WHITE)
        for j in range(1, n_out[a]):
            m.add(geo.resample(line(a, -j * w, r, length), 1.0), BROKEN_WHITE)
        m.add(geo.resample(line(a, 0.0, r, length), 1.0), SOLID_DOUBLE_YELLOW)
        if a in stop_arms:  # WOMD stop signs are single points beside the stop line
            m.add(along(a, n_in[a] * w + 0.8)(r + STOP_LINE)[None], RG_STOP_SIGN)
        _crosswalk(m, u[a] * (r + 2.0) + nrm[a] * (n_in[a] - n_out[a]) * w / 2, nrm[a],
                   (n_in[a] + n_out[a]) * w / 2, 1.5)
    # Corners: arm a's left side (inwards) -> rounded corner -> next arm's right side (outwards).
    for a in range(n_arms):
        b = (a + 1) % n_arms
        p0, p1 = along(a, n_in[a] * w)(r), along(b, -n_out[b] * w)(r)
        c = 0.39 * np.linalg.norm(p1 - p0)
        bend = geo.bezier_cubic(p0, -u[a] * c, p1, u[b] * c, 40)
        edge = geo.concat(line(a, n_in[a] * w, length, r), bend, line(b, -n_out[b] * w, r, length))
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
                elif turn < 0:
                    kind, k = "right", 0
                    if j != 0:
                        continue
                else:
                    kind, k = "left", n_out[b] - 1
                    if j != n_in[a] - 1:
                        continue
                start, end = ins[a, j][-1], outs[b, k][0]
                c = 0.4 * np.linalg.norm(end - start)
                conn = geo.bezier_cubic(start, -u[a] * c, end, u[b] * c, 30)
                m.add(conn, RG_LANE_SURFACE_STREET)
                path = geo.concat(ins[a, j], conn, outs[b, k])
                route = _route(path, group, kind, limit)
                route.entry = float(geo.arc_length(ins[a, j])[-1])
                if a in stop_arms:
                    route.stop_at = route.entry - STOP_LINE
                m.routes.append(route)
            group += 1
    return m
