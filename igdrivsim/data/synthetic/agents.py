"""Agents and their longitudinal planner: IDM car-following over a space-time occupancy map.

Agents are planned one by one in priority order: each follows those planned before it ahead on
its route, yields to crossing ones, and slows early for curves, stop signs and lights.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass
from math import sqrt

import numpy as np

from igdrivsim.data.scenario import DT, NUM_STEPS, TYPE_VEHICLE
from igdrivsim.data.synthetic.maps import LIGHT_CAUTION, LIGHT_GO, Route

T = NUM_STEPS
LOOKAHEAD = 120.0  # m of route an agent watches ahead
A_LAT = 2.2  # m/s^2 comfortable lateral acceleration in curves
B_MAX = 7.0  # m/s^2 hardest braking
STOP_WAIT = 8  # steps an agent stands at a stop sign
PARALLEL = ("lane", "bike")  # road-map route kinds that never cover each other's lanes
ON_ROAD = (*PARALLEL, "change", "merge")  # road-map routes >= 3 m from the sidewalks


@dataclass
class Agent:
    """One object: its route, size, driver parameters and (once planned) its trajectory."""

    route: Route
    s0: float
    v0: float
    length: float
    width: float
    height: float
    obj_type: int = TYPE_VEHICLE
    v_des: float = 12.0
    accel: float = 1.5  # IDM a
    brake: float = 2.0  # IDM b (comfortable)
    headway: float = 1.4  # IDM T
    min_gap: float = 2.5  # IDM s0
    static: bool = False  # stands still for the whole log
    walker: bool = False  # constant-speed pedestrian, ignores others
    start_step: int = 0  # walkers: first step in motion
    stop_window: tuple[int, int] | None = None  # braking leader: stop during these steps
    lateral: tuple[float, float, float] = (0.0, 60.0, 0.0)  # amplitude, wavelength, phase
    offset: float = 0.0  # m: constant lateral offset from the route (left positive)
    speed_wave: tuple[float, float, float] | None = None  # v_des x (1 + a sin(2 pi t / T + p))
    is_sdc: bool = False
    role: str = "background"
    # filled by plan()
    s: np.ndarray | None = None
    valid: np.ndarray | None = None
    xy: np.ndarray | None = None
    yaw: np.ndarray | None = None
    speed: np.ndarray | None = None
    reach: float = 0.0  # half the box diagonal
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # of the valid centres: lo, hi
    track: np.ndarray | None = None  # moving agents: [7, T] x, y, yaw, cos, sin, speed, valid


def speed_profile(route: Route, v_des: float, brake: float) -> np.ndarray:
    """Desired speed per route point: ``v_des``, sqrt(A_LAT / |kappa|), and braking early enough
    (at ``brake``) for every slower point ahead."""
    v = np.minimum(v_des, np.sqrt(A_LAT / np.maximum(route.smooth_curvature, 1e-6)))
    s = route.s
    # v[k]^2 <= v[j]^2 + 2 b (s_j - s_k) for all j >= k: a reversed running minimum.
    reach = np.minimum.accumulate((v**2 + 2 * brake * s)[::-1])[::-1]
    return np.sqrt(np.maximum(reach - 2 * brake * s, 0.0))


def _occupancy(agent: Agent, yaw_route: np.ndarray, others: list[Agent]):
    """Where and when ``others`` cover ``agent``'s route: ``(rows [P], occ [P, T], along [P, T])``
    per (other, covered route point); ``along``: its speed along the route (NaN: crossing)."""
    lo, hi = agent.route.bounds
    none = (np.zeros(0, int), np.zeros((0, T), bool), np.zeros((0, T)))
    if not others:
        return none
    reach = np.array([o.reach for o in others]) + agent.width / 2 + 1.0
    box = np.array([o.bbox for o in others])
    olo, ohi = box[:, :2], box[:, 2:]
    meets = ((olo - reach[:, None] <= hi) & (ohi + reach[:, None] >= lo)).all(1)
    if not meets.any():
        return none
    others = [o for o, m in zip(others, meets, strict=True) if m]
    olo, ohi = olo[meets] - reach[meets, None], ohi[meets] + reach[meets, None]
    px, py = agent.route.points.T
    j, k = np.nonzero((px >= olo[:, :1]) & (px <= ohi[:, :1]) & (py >= olo[:, 1:])
                      & (py <= ohi[:, 1:]))
    if len(k) == 0:
        return none
    track = np.stack([o.track for o in others])  # [O, 7, T], see Agent.track
    size = np.array([(o.length, o.width) for o in others])[j]
    c, s = track[j, 3], track[j, 4]
    d0, d1 = px[k, None] - track[j, 0], py[k, None] - track[j, 1]  # [P, T]
    # the point within the other's box grown by agent's half width + 0.4 m, at a valid step
    grow = agent.width / 2 + 0.4
    dx = np.abs(d0 * c + d1 * s) - size[:, :1] / 2
    dy = np.abs(d1 * c - d0 * s) - size[:, 1:] / 2
    occ = (dx < grow) & (dy < grow) & (track[j, 6] > 0.5)
    keep = occ.any(1)
    j, k, occ = j[keep], k[keep], occ[keep]
    cosang = np.cos(track[j, 2] - yaw_route[k, None])
    along = np.where(cosang > 0.75, track[j, 5] * cosang, np.nan)
    return k, occ, along


def _may_cover(agent: Agent, xy: np.ndarray, yaw: np.ndarray, length, width) -> np.ndarray:
    """Whether boxes at ``xy [N, 2]`` (heading ``yaw``) may cover a point of ``agent``'s route
    (conservative: a box whose grown rectangle the locally straight route misses is out)."""
    route = agent.route
    _, k = route.tree.query(xy)
    rel, t = xy - route.points[k], route.tangents[k]
    lateral = np.abs(t[:, 0] * rel[:, 1] - t[:, 1] * rel[:, 0])
    dyaw = yaw - route.yaw[k]
    grow = agent.width / 2 + 0.4
    bound = ((length / 2 + grow) * np.abs(np.sin(dyaw)) + (width / 2 + grow) * np.abs(np.cos(dyaw))
             + 0.7)
    end = (k == 0) | (k == len(route.points) - 1)
    return (lateral < bound) | (end & (np.hypot(*rel.T) < np.hypot(length / 2 + grow,
                                                                     width / 2 + grow) + 0.7))


def _standing_hits(agent: Agent, yaw_route: np.ndarray, fixed: list[Agent]):
    """Route points covered by standing objects, as :func:`_occupancy` (``along`` 0: aligned)."""
    lo, hi = agent.route.bounds
    stand = np.array([(*o.bbox[:2], o.yaw[0], o.length, o.width, o.reach) for o in fixed])
    xy, yaw, size = stand[:, :2], stand[:, 2], stand[:, 3:5]
    reach = stand[:, 5] + agent.width / 2 + 1.0
    near = ((xy >= lo - reach[:, None]) & (xy <= hi + reach[:, None])).all(1)
    if near.any():
        near[near] = _may_cover(agent, xy[near], yaw[near], size[near, 0], size[near, 1])
    if not near.any():
        return np.zeros(0, int), np.zeros((0, T), bool), np.zeros((0, T))
    xy, yaw, size = xy[near], yaw[near], size[near]
    d = agent.route.points[:, None, :] - xy[None]
    c, s = np.cos(yaw), np.sin(yaw)
    dx = np.abs(d[..., 0] * c + d[..., 1] * s) - size[:, 0] / 2
    dy = np.abs(-d[..., 0] * s + d[..., 1] * c) - size[:, 1] / 2
    k, j = np.nonzero(np.maximum(dx, dy) < agent.width / 2 + 0.4)
    along = np.where(np.cos(yaw[j] - yaw_route[k]) > 0.75, 0.0, np.nan)
    return k, np.ones((len(k), T), bool), np.repeat(along[:, None], T, 1)


def plan(agent: Agent, planned: list[Agent]) -> None:
    """Fill ``agent.s/valid/xy/yaw`` by simulating IDM against the already ``planned`` agents."""
    if agent.static:  # posed by pose_standing, with the other standing agents at once
        return
    if agent.walker:  # constant speed from start_step on
        s = agent.s0 + agent.v0 * (np.clip(np.arange(T) - agent.start_step, 0, None) * DT)
    else:
        s = _simulate(agent, agent.route.s, planned)
    valid, xy, yaw = _pose_at([agent], s[None])
    agent.s, agent.valid, agent.xy, agent.yaw = s, valid[0], xy[0], yaw[0]
    agent.reach = float(np.hypot(agent.length, agent.width) / 2)
    agent.speed = np.hypot(*np.gradient(agent.xy, DT, axis=0).T)
    where = agent.xy[agent.valid] if agent.valid.any() else agent.xy[:1]
    agent.bbox = (*where.min(0).tolist(), *where.max(0).tolist())
    agent.track = np.stack([*agent.xy.T, agent.yaw, np.cos(agent.yaw), np.sin(agent.yaw),
                            agent.speed, agent.valid])


def pose_standing(agents: list[Agent]) -> None:
    """Plan static agents (one pose, repeated; they ignore the others), one batch per route."""
    by_route: dict[int, list[Agent]] = {}
    for a in agents:
        by_route.setdefault(id(a.route), []).append(a)
    for group in by_route.values():
        s = np.array([a.s0 for a in group], float)[:, None] + 0.0  # [N, 1]
        valid, xy, yaw = _pose_at(group, s)
        for i, a in enumerate(group):
            a.s, a.valid, a.speed = np.full(T, s[i, 0]), np.full(T, valid[i, 0]), np.zeros(T)
            a.xy, a.yaw = np.repeat(xy[i], T, 0), np.full(T, yaw[i, 0])
            a.reach = float(np.hypot(a.length, a.width) / 2)
            a.bbox = (*xy[i, 0].tolist(),) * 2


def _simulate(agent: Agent, s_route: np.ndarray, planned: list[Agent]) -> np.ndarray:
    yaw_route = agent.route.yaw
    v_prof = speed_profile(agent.route, agent.v_des, agent.brake).tolist()
    group, parallel = agent.route.group, agent.route.kind in PARALLEL
    on_road = agent.route.kind in ON_ROAD
    # the other moving agents, but neither another lane of the road (a lane's width away) nor,
    # for a road user, a pedestrian on the sidewalk (2 m outside the road edge)
    moving = [o for o in planned if not o.static
              and not (parallel and o.route.kind in PARALLEL and o.route.group != group)
              and not (on_road and o.role == "stroller")]
    fixed = [o for o in planned if o.static]  # planned ones stand at every step
    hits = [_standing_hits(agent, yaw_route, fixed)] if fixed else []
    follow_rows, follow_t, follow_v, cross_rows, cross_occ = [], [], [], [], []
    for rows, occ, along in [*hits, _occupancy(agent, yaw_route, moving)]:
        k, t = np.nonzero(occ & ~np.isnan(along))  # aligned: followed; the others: crossed
        follow_rows.append(rows[k]), follow_t.append(t), follow_v.append(along[k, t])
        cross = occ & np.isnan(along)
        keep = cross.any(1)
        if keep.any():
            cross_rows.append(rows[keep]), cross_occ.append(cross[keep])
    # Follow obstacles: route distances and leader speeds, step t's in f_s[f_at[t]:f_at[t + 1]]
    k, t, v = (np.concatenate(x) for x in (follow_rows, follow_t, follow_v))
    order = np.lexsort((k, t))
    f_s, f_v = s_route[k[order]].tolist(), v[order].tolist()
    f_at = np.searchsorted(t[order], np.arange(T + 1)).tolist()
    if cross_rows:
        c_s = s_route[np.concatenate(cross_rows)]
        times = np.where(np.concatenate(cross_occ, 0), np.arange(T)[None], 10 * T).astype(float)
        next_occ = np.minimum.accumulate(times[:, ::-1], axis=1)[:, ::-1]  # first step >= t
        order = np.argsort(c_s, kind="stable")  # sorted: the window ahead is a slice
        # Python lists (bisect: np.searchsorted's answer without its overhead); occ_lists[t]
        c_list, occ_lists = c_s[order].tolist(), next_occ[order].T.tolist()
    # The step loop runs on Python floats (numpy scalars are slower; the same IEEE arithmetic).
    half, length = agent.length / 2, float(agent.length)
    accel, brake = float(agent.accel), float(agent.brake)
    headway, min_gap = float(agent.headway), float(agent.min_gap)
    sqrt_ab = float(2 * np.sqrt(agent.accel * agent.brake))
    pos, v = float(agent.s0), float(agent.v0)
    stop_at, waited, on_yellow = 0.0, 0, False
    stop_line, signal, signal_at = agent.route.stop_at, None, agent.route.signal_at
    if stop_line is not None:  # None when already past it
        stop_line = float(stop_line) if agent.s0 + half <= stop_line - 0.5 else None
    if agent.route.signal is not None and agent.s0 + half <= signal_at - 0.5:
        signal, signal_at = agent.route.signal.tolist(), float(signal_at)
    inv_ds, last = float((len(s_route) - 1) / s_route[-1]), len(s_route) - 1
    wave = agent.speed_wave
    window = agent.stop_window if agent.stop_window is not None else (0, 0)
    out = []
    for t in range(T):
        out.append(pos)
        front = pos + half
        gap, v_lead = LOOKAHEAD, v
        lo, hi = f_at[t], f_at[t + 1]
        if hi > lo:  # sorted: the first occupied point ahead of our front bumper
            i = bisect_right(f_s, front - 0.5, lo, hi)
            if i < hi and f_s[i] < front + LOOKAHEAD:
                gap, v_lead = f_s[i] - front, max(f_v[i], 0.0)
        if cross_rows:
            commit = v * v / (2 * B_MAX * 0.6)
            i0 = bisect_right(c_list, front + commit)
            i1 = bisect_left(c_list, front + LOOKAHEAD)
            if i1 > i0:  # the nearest point ahead that is occupied before we could clear it
                clear = (length + 4.0) / max(v, 3.0) + 1.0
                occ_t, nearest = occ_lists[t], None
                for i in range(i0, i1):
                    d = c_list[i] - front
                    if occ_t[i] <= t + (d / max(v, sqrt(accel * d)) + clear) / DT:
                        nearest = d  # ascending arc lengths: the first hit is the nearest
                        break
                if nearest is not None:
                    g = nearest - 1.5
                    if g < gap:
                        gap, v_lead = g, 0.0
        if stop_line is not None:  # stop sign: come to a full stop, wait, then go
            g = stop_line - front
            if g < -1.0 or waited >= STOP_WAIT:
                stop_line = None
            else:
                waited += v < 0.3 and g < 2.0
                g += min_gap - 0.5  # stand just behind the line, not min_gap before it
                if g < gap:
                    gap, v_lead = max(g, 0.05), 0.0
        if signal is not None:  # traffic light: stop at red, and at yellow when comfortable
            g = signal_at - front
            if g < -1.0:
                signal = None
            elif signal[t] != LIGHT_GO and not on_yellow:
                if signal[t] == LIGHT_CAUTION and v * v > 2 * 1.3 * brake * max(g, 0.1):
                    on_yellow = True  # too close to stop comfortably: it clears on yellow
                else:
                    g += min_gap - 0.5
                    if g < gap:
                        gap, v_lead = max(g, 0.05), 0.0
        if window[0] <= t < window[1]:  # a braking leader's stop
            if t == window[0]:
                stop_at = pos + max(v * v / (2 * brake * 1.3), 3.0) + half
            g = stop_at - front
            if g < gap:
                gap, v_lead = g, 0.0
        if t == 0:  # start no faster than the speed whose IDM s* is 1.2 gap (no brake slam)
            inv, b = 1.0 / sqrt_ab, headway - v_lead / sqrt_ab
            disc = b * b - 4 * inv * (min_gap - 1.2 * gap)
            v = min(v, max((-b + disc**0.5) / (2 * inv), 0.0) if disc >= 0 else 0.0)
        k = min(max(int(pos * inv_ds + 0.5), 0), last)
        v_d = max(v_prof[k], 0.1)
        if wave is not None:  # a driver who does not hold the speed exactly
            v_d *= 1.0 + wave[0] * float(np.sin(2 * np.pi * t * DT / wave[1] + wave[2]))
        free = accel * (1 - (v / v_d) ** 4)
        if v_lead < 0.3 and gap < LOOKAHEAD:
            # stop ``room`` ahead like a driver: roll on while the needed deceleration is
            # below 0.8 of the comfortable one, then brake at the needed constant rate
            room = gap - min_gap
            if room <= 0.2:
                stopping = -min(v / DT, B_MAX)
            else:
                need = v * v / (2 * room)
                start = 0.8 * brake
                stopping = accel * (1 - need / start) if need < start else -need
            acc = min(free, stopping)
        else:
            s_star = min_gap + max(0.0, v * headway + v * (v - v_lead) / sqrt_ab)
            acc = free - accel * (s_star / max(gap, 0.1)) ** 2
        acc = min(max(acc, -B_MAX), accel)
        v_new = max(v + acc * DT, 0.0)
        pos += 0.5 * (v + v_new) * DT
        v = v_new
    return np.array(out)


def stop_cap(agent: Agent) -> float:
    """The largest start speed that stops (at 1.5 m/s^2) before a stop sign or light ahead."""
    route = agent.route
    lines = [route.stop_at]
    if route.signal is not None and route.signal[0] != LIGHT_GO:
        lines.append(route.signal_at)
    rooms = [max(line - agent.s0 - agent.length / 2 - 1.0, 0.0) for line in lines
             if line is not None and agent.s0 < line]
    return min((float(np.sqrt(2 * 1.5 * room)) for room in rooms), default=np.inf)


def _pose_at(agents: list[Agent], s: np.ndarray):
    """Poses ``(valid, xy, yaw)`` of ``agents`` (one route) at ``s [N, S]``, with lateral wander."""
    route = agents[0].route
    s_route, pts = route.s, route.points
    valid = (s >= 0) & (s <= s_route[-1] - 0.5)
    sc = np.clip(s, 0, s_route[-1])
    x, y = np.interp(sc, s_route, pts[:, 0]), np.interp(sc, s_route, pts[:, 1])
    yaw_r = np.interp(sc, s_route, route.yaw)
    amp, wave, phase = np.array([a.lateral for a in agents], float).T[..., None]  # [N, 1]
    k = 2 * np.pi / wave
    off = amp * np.sin(k * sc + phase)
    offset = np.array([a.offset for a in agents], float)[:, None]
    off = np.where(offset != 0, off + offset, off)  # (an offset of 0 keeps off's sign bit)
    slope = amp * k * np.cos(k * sc + phase)
    nx, ny = -np.sin(yaw_r), np.cos(yaw_r)
    return valid, np.stack([x + off * nx, y + off * ny], -1), yaw_r + np.arctan(slope)


def box_corners(xy: np.ndarray, yaw: np.ndarray, length, width) -> np.ndarray:
    """Corners ``[..., 4, 2]`` of oriented boxes."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    lx = np.array([1, 1, -1, -1]) * np.asarray(length)[..., None] / 2
    ly = np.array([1, -1, -1, 1]) * np.asarray(width)[..., None] / 2
    return np.stack([xy[..., None, 0] + lx * c - ly * s, xy[..., None, 1] + lx * s + ly * c], -1)


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Separating-axis test for convex quads given as corners ``[..., 4, 2]``."""
    edges = np.concatenate([a[..., 1:3, :] - a[..., :2, :], b[..., 1:3, :] - b[..., :2, :]], -2)
    nx, ny = -edges[..., 1:], edges[..., :1]  # [..., 4 axes, 1]
    pa = a[..., None, :, 0] * nx + a[..., None, :, 1] * ny  # [..., 4 axes, 4 corners]
    pb = b[..., None, :, 0] * nx + b[..., None, :, 1] * ny
    return ((pa.max(-1) > pb.min(-1)) & (pb.max(-1) > pa.min(-1))).all(-1)


def collides_any(a: Agent, others: list[Agent]) -> bool:
    """Whether ``a``'s box overlaps one of ``others``' at a step where both are valid."""
    if a.route.kind in PARALLEL:
        others = [b for b in others
                  if not (b.route.kind in PARALLEL and b.route.group != a.route.group)]
    if not others:
        return False
    reach = a.reach + np.array([b.reach for b in others])
    box = np.array([b.bbox for b in others])  # lo x, lo y, hi x, hi y
    meet = ~((a.bbox[0] - reach > box[:, 2]) | (a.bbox[2] + reach < box[:, 0])
             | (a.bbox[1] - reach > box[:, 3]) | (a.bbox[3] + reach < box[:, 1]))
    if not meet.any():
        return False
    others, reach = [b for b, m in zip(others, meet, strict=True) if m], reach[meet]
    valid = np.stack([b.valid for b in others]) & a.valid  # [N, T]
    xy = np.stack([b.xy for b in others])  # [N, T, 2]
    d = (a.xy[None] - xy).reshape(-1, 2)
    n, t = np.nonzero(valid & (np.einsum("ij,ij->i", d, d).reshape(valid.shape)
                               < (reach * reach)[:, None]))
    if len(n) == 0:
        return False
    size = np.array([(b.length, b.width) for b in others])
    yaw = np.stack([b.yaw for b in others])
    ca = box_corners(a.xy[t], a.yaw[t], a.length, a.width)
    cb = box_corners(xy[n, t], yaw[n, t], size[n, 0], size[n, 1])
    return bool(boxes_overlap(ca, cb).any())
