"""Motion statistics of logged trajectories (``igdrivsim stats``; offline, NumPy).

Two groups per scenario: the SDC, and the other moving agents (vehicles and cyclists with more
than 10 valid steps and a path extent of at least 1 m, as in :mod:`igdrivsim.data.stats`;
pedestrians are left out: lanes, curvature and constant velocity mean little for them).

Definitions (``DT`` = 0.1 s, ``LAG`` = 4 steps = 0.4 s, every rate is a difference over ``LAG``):

- constant-velocity distance at horizon H (1, 3, 5, 8 s): from the state at the current step
  (index 10, t = 1.0 s), ``e = p(10 + 10 H) - (p(10) + v(10) H)`` with the logged velocity
  ``v(10)``; ``cv_distance = |e|``, ``cv_along`` = e along the heading at index 10 (signed:
  negative = behind the extrapolation), ``cv_across`` = |e across that heading|;
- speed over a window: ``|p(t + LAG) - p(t)| / 0.4 s``; acceleration: the change of that speed
  over ``LAG``; longitudinal jerk: the change of that acceleration over ``LAG``;
- yaw rate: the wrapped change of the logged yaw over ``LAG`` / 0.4 s, and curvature: yaw rate /
  speed, both over windows with speed > 1 m/s;
- lateral lane offset: signed distance (left positive) from the nearest lane-centre point
  (lane types freeway, surface street, bike) whose direction is within 60 degrees of the
  agent's heading, within 10 m; its rate over ``LAG`` while that lane polyline stays the same;
- lane change (per agent, over the future t >= 1.0 s): from one step to the next, the matched
  lane-centre polyline changes from A to B, B's centre lies 2.5-5 m beside A's (a neighbouring
  lane: not a successor, a branch or overlapping junction lanes) and the agent has crossed half
  of that lane width into B's lane; a change back within 2 s cancels both (jitter at a lane line);
- turn (per agent, 0 or 1): the net (unwrapped) heading change between the first and last
  future windows in which the agent moves (speed > 1 m/s) exceeds 45 degrees;
- share stopped: the share of the future windows with speed < 0.5 m/s.
"""

from __future__ import annotations

from collections import defaultdict
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from igdrivsim.data.filter import valid_xy
from igdrivsim.data.scenario import CURRENT_INDEX, DT, TYPE_CYCLIST, TYPE_VEHICLE, Scenario
from igdrivsim.data.stats import (
    ACCEL_LAG,
    LANE_TYPES,
    MAX_POLYLINE_GAP,
    STATIC_M,
    STATIC_MIN_STEPS,
    Statistic,
    histogram,
    js_divergence,
    path_extent,
    summary,
)
from igdrivsim.io import atomic_savefig

LAG = ACCEL_LAG  # steps (0.4 s) of every difference
HORIZONS = (1, 3, 5, 8)  # s
MOVING_SPEED = 1.0  # m/s: yaw rate, curvature and turns only above it
STOPPED_SPEED = 0.5  # m/s
TURN_DEG = 45.0
LANE_HEADING_DEG = 60.0  # a lane point counts when its direction is this close to the heading
LANE_MAX_DISTANCE = 10.0  # m: farther from every aligned lane centre: off the lane network
LANE_NEIGHBOURS = 64  # nearest lane points searched for an aligned one
MIN_LANE_SEPARATION, MAX_LANE_SEPARATION = 2.5, 5.0  # m: centres this far apart: neighbours
CROSS_TOLERANCE = 0.25  # m: slack on "crossed half the lane width"
CANCEL_STEPS = 20  # a lane change undone within 2 s is jitter (a car on a lane line)
GROUPS = ("sdc", "others")
GROUP_LABELS = {"sdc": "SDC", "others": "other moving agents"}
GROUP_SHORT = {"sdc": "SDC", "others": "others"}
AGENT_TYPES = (TYPE_VEHICLE, TYPE_CYCLIST)


def _cv(h: int) -> tuple[Statistic, ...]:
    top = {1: 5.0, 3: 20.0, 5: 40.0, 8: 80.0}[h]
    return (Statistic(f"cv_distance_{h}s", f"CV distance at {h} s", "m",
                      np.linspace(0, top, 51), "agent"),
            Statistic(f"cv_along_{h}s", f"CV distance along the heading at {h} s", "m",
                      np.linspace(-top, top, 81), "agent"),
            Statistic(f"cv_across_{h}s", f"CV distance across the heading at {h} s (abs.)",
                      "m", np.linspace(0, top / 2, 51), "agent"))


MOTION_STATISTICS: tuple[Statistic, ...] = (
    *(s for h in HORIZONS for s in _cv(h)),
    Statistic("speed", "speed", "m/s", np.linspace(0, 30, 61)),
    Statistic("acceleration", "acceleration", "m/s^2", np.linspace(-8, 8, 65)),
    Statistic("jerk", "longitudinal jerk", "m/s^3", np.linspace(-10, 10, 81)),
    Statistic("yaw_rate", "yaw rate (speed > 1 m/s)", "rad/s", np.linspace(-0.5, 0.5, 81)),
    Statistic("curvature", "curvature (speed > 1 m/s)", "1/m", np.linspace(-0.1, 0.1, 81)),
    Statistic("lane_offset", "lateral offset from the lane centre", "m", np.linspace(-4, 4, 81)),
    Statistic("lane_offset_rate", "lateral offset rate", "m/s", np.linspace(-2, 2, 81)),
    Statistic("stopped_share", "share of the future stopped (< 0.5 m/s)", "",
              np.linspace(0, 1, 21), "agent"),
    Statistic("lane_changes", "lane changes per agent (mean)", "", np.arange(-0.5, 6.0), "agent",
              count=True),
    Statistic("turns", "turns > 45 deg per agent (mean)", "", np.arange(-0.5, 2.0), "agent",
              count=True),
)
AGENT_KEYS = tuple(s.key for s in MOTION_STATISTICS if s.per == "agent")
STEP_KEYS = tuple(s.key for s in MOTION_STATISTICS if s.per == "step")


def _cross(d: np.ndarray, v: np.ndarray) -> np.ndarray:
    return d[..., 0] * v[..., 1] - d[..., 1] * v[..., 0]


class LaneMap:
    """Lane-centre points of one scenario with unit directions along their polyline."""

    def __init__(self, xy: np.ndarray, ids: np.ndarray):
        step = np.diff(xy, axis=0)
        gap = np.linalg.norm(step, axis=1)
        same = (ids[1:] == ids[:-1]) & (gap > 0) & (gap <= MAX_POLYLINE_GAP)
        fwd, back = np.zeros_like(xy), np.zeros_like(xy)
        fwd[:-1][same], back[1:][same] = step[same], step[same]
        d = np.where(np.linalg.norm(fwd, axis=1, keepdims=True) > 0, fwd, back)
        norm = np.linalg.norm(d, axis=1)
        keep = norm > 0  # a lone point has no direction
        self.xy, self.ids = xy[keep], ids[keep]
        self.dir = d[keep] / norm[keep, None]
        self.tree = cKDTree(self.xy) if len(self.xy) else None
        self._points: dict[int, np.ndarray] = {}

    @classmethod
    def of(cls, scenario: Scenario) -> LaneMap:
        rg = scenario.roadgraph
        sel = np.asarray(rg.valid, bool) & np.isin(np.asarray(rg.type), LANE_TYPES)
        return cls(np.asarray(rg.xyz, np.float64)[sel, :2], np.asarray(rg.id)[sel])

    def match(self, xy: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per position: signed lateral offset (m, left positive) from the nearest aligned lane
        point and that point's index (NaN and -1 where there is none)."""
        offset, index = np.full(len(xy), np.nan), np.full(len(xy), -1)
        if self.tree is None or not len(xy):
            return offset, index
        n = len(self.xy)
        k = min(LANE_NEIGHBOURS, n)
        _, j = self.tree.query(xy, k=k, distance_upper_bound=LANE_MAX_DISTANCE)
        j = j.reshape(len(xy), k)
        found = j < n
        heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)
        cos = (self.dir[np.minimum(j, n - 1)] * heading[:, None]).sum(-1)
        aligned = found & (cos >= np.cos(np.radians(LANE_HEADING_DEG)))
        has = aligned.any(1)
        best = j[np.arange(len(xy)), np.argmax(aligned, 1)][has]
        offset[has] = _cross(self.dir[best], xy[has] - self.xy[best])
        index[has] = best
        return offset, index

    def _nearest_on(self, lane: int, p: np.ndarray) -> int:
        if (pts := self._points.get(lane)) is None:
            pts = self._points[lane] = np.flatnonzero(self.ids == lane)
        return int(pts[np.argmin(np.linalg.norm(self.xy[pts] - p, axis=1))])

    def crossed(self, a: int, b: int, p: np.ndarray) -> bool:
        """Whether a step to position ``p``, matched to lane point ``b`` after lane point ``a``
        of another polyline, is a lane change (module docstring)."""
        qa = self._nearest_on(int(self.ids[a]), p)
        d = self.dir[qa]
        sep = float(_cross(d, self.xy[b] - self.xy[qa]))
        off = float(_cross(d, p - self.xy[qa]))
        off_b = float(_cross(self.dir[b], p - self.xy[b]))
        half = abs(sep) / 2
        return (MIN_LANE_SEPARATION <= abs(sep) <= MAX_LANE_SEPARATION
                and off * np.sign(sep) >= half - CROSS_TOLERANCE
                and abs(off_b) <= half + CROSS_TOLERANCE)  # now within B's lane

    def lane_changes(self, xy: np.ndarray, index: np.ndarray, start: int) -> int:
        """Lane changes from step ``start`` on, given the matched point ``index`` per step."""
        events: list[tuple[int, int, int]] = []  # (step, from lane id, to lane id)
        prev = -1
        for t in range(start, len(xy)):
            if index[t] < 0:  # off the lanes (or invalid): no comparison across the gap
                prev = -1
                continue
            a, b = int(self.ids[prev]), int(self.ids[index[t]])
            if prev >= 0 and a != b and self.crossed(prev, index[t], xy[t]):
                events.append((t, a, b))
            prev = index[t]
        count, i = 0, 0
        while i < len(events):
            nxt = events[i + 1] if i + 1 < len(events) else None
            if nxt is not None and nxt[2] == events[i][1] and nxt[0] - events[i][0] <= CANCEL_STEPS:
                i += 2  # there and back at once: jitter
                continue
            count, i = count + 1, i + 1
        return count


def agent_motion(xy: np.ndarray, yaw: np.ndarray, vel: np.ndarray, valid: np.ndarray,
                 lanes: LaneMap | None = None, start: int = CURRENT_INDEX
                 ) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Motion statistics of one agent's log (``xy`` [T, 2], ``yaw`` [T], ``vel`` [T, 2],
    ``valid`` [T]): ``(per-agent values, per-window samples)`` keyed as
    :data:`AGENT_KEYS` and :data:`STEP_KEYS`."""
    xy, vel = np.asarray(xy, np.float64), np.asarray(vel, np.float64)
    yaw, valid = np.asarray(yaw, np.float64), np.asarray(valid, bool)
    steps = len(valid)
    out: dict[str, float] = dict.fromkeys(AGENT_KEYS, np.nan)
    if valid[start]:
        fwd = np.array([np.cos(yaw[start]), np.sin(yaw[start])])
        for h in HORIZONS:
            k = start + round(h / DT)
            if k < steps and valid[k]:
                e = xy[k] - (xy[start] + vel[start] * h)
                out[f"cv_distance_{h}s"] = float(np.linalg.norm(e))
                out[f"cv_along_{h}s"] = float(e @ fwd)
                out[f"cv_across_{h}s"] = abs(float(_cross(fwd, e)))
    span = LAG * DT
    ok = valid[LAG:] & valid[:-LAG]  # window [t, t + LAG]
    speed = np.linalg.norm(xy[LAG:] - xy[:-LAG], axis=1) / span
    yaw_rate = ((yaw[LAG:] - yaw[:-LAG] + np.pi) % (2 * np.pi) - np.pi) / span  # change wrapped
    moving = ok & (speed > MOVING_SPEED)
    acc = (speed[LAG:] - speed[:-LAG]) / span
    acc_ok = ok[LAG:] & ok[:-LAG]
    jerk = (acc[LAG:] - acc[:-LAG]) / span
    jerk_ok = acc_ok[LAG:] & acc_ok[:-LAG]
    samples = {"speed": speed[ok], "acceleration": acc[acc_ok], "jerk": jerk[jerk_ok],
               "yaw_rate": yaw_rate[moving], "curvature": yaw_rate[moving] / speed[moving]}
    future = ok[start:]
    if future.any():
        out["stopped_share"] = float((speed[start:][future] < STOPPED_SPEED).mean())
        move = np.flatnonzero(moving[start:]) + start
        turn = np.unwrap(yaw[move]) if len(move) > 1 else np.zeros(1)
        out["turns"] = float(abs(turn[-1] - turn[0]) > np.radians(TURN_DEG))
    if lanes is not None and lanes.tree is not None:
        offset, index = np.full(steps, np.nan), np.full(steps, -1)
        offset[valid], index[valid] = lanes.match(xy[valid], yaw[valid])
        same = (index[LAG:] >= 0) & (index[:-LAG] >= 0)
        same[same] = lanes.ids[index[LAG:][same]] == lanes.ids[index[:-LAG][same]]
        samples["lane_offset"] = offset[np.isfinite(offset)]
        samples["lane_offset_rate"] = ((offset[LAG:] - offset[:-LAG]) / span)[same]
        if valid[start:].any():
            out["lane_changes"] = float(lanes.lane_changes(xy, index, start))
    else:
        samples["lane_offset"] = samples["lane_offset_rate"] = np.zeros(0)
    return out, {k: samples[k].astype(np.float32) for k in STEP_KEYS}


class Motion(NamedTuple):
    """One scenario's motion statistics: one row per agent (``group``, ``object`` and
    :data:`AGENT_KEYS`) and the per-window samples per group."""

    agents: list[dict]
    samples: dict[str, dict[str, np.ndarray]]


def motion_agents(scenario: Scenario) -> tuple[int | None, np.ndarray]:
    """The SDC's index (None when it has no valid step) and the other moving agents' indices."""
    md = scenario.metadata
    valid, xy = valid_xy(scenario)
    sdc = int(np.argmax(np.asarray(md.is_sdc)))
    moving = ((valid.sum(1) > STATIC_MIN_STEPS) & (path_extent(xy, valid) >= STATIC_M)
              & np.isin(np.asarray(md.object_type), AGENT_TYPES))
    moving[sdc] = False
    return (sdc if valid[sdc].any() else None), np.flatnonzero(moving)


def motion_statistics(scenario: Scenario) -> Motion:
    """Motion statistics of one unbatched scenario (module docstring)."""
    tr = scenario.trajectory
    valid, xy = valid_xy(scenario)
    vel = np.stack([np.asarray(tr.vel_x), np.asarray(tr.vel_y)], -1)
    yaw = np.asarray(tr.yaw)
    lanes = LaneMap.of(scenario)
    sdc, others = motion_agents(scenario)
    agents: list[dict] = []
    parts: dict[str, dict[str, list]] = {g: defaultdict(list) for g in GROUPS}
    chosen = ([] if sdc is None else [(sdc, "sdc")]) + [(int(i), "others") for i in others]
    for i, group in chosen:
        row, samples = agent_motion(xy[i], yaw[i], vel[i], valid[i], lanes)
        agents.append({"group": group, "object": i, **row})
        for k, v in samples.items():
            parts[group][k].append(v)
    return Motion(agents, {g: {k: np.concatenate(parts[g][k]) if parts[g][k] else np.zeros(0)
                               for k in STEP_KEYS} for g in GROUPS})


class MotionPool:
    """A data set's per-agent values and per-window samples, per group, kept per scenario (the
    unit :func:`js_floor` resamples)."""

    def __init__(self) -> None:
        self.units: dict[str, list[dict[str, np.ndarray]]] = {g: [] for g in GROUPS}
        self.agents = dict.fromkeys(GROUPS, 0)
        self.scenarios = 0
        self._joined: dict[tuple[str, str], np.ndarray] = {}

    def add(self, motion: Motion) -> None:
        self.scenarios += 1
        self._joined.clear()
        for g in GROUPS:
            rows = [row for row in motion.agents if row["group"] == g]
            if rows:
                self.agents[g] += len(rows)
                self.units[g].append({**{k: np.array([r[k] for r in rows], np.float64)
                                         for k in AGENT_KEYS}, **motion.samples[g]})

    def values(self, group: str, key: str) -> np.ndarray:
        """The finite values of ``key`` pooled over the scenarios added."""
        if (group, key) not in self._joined:
            parts = [u[key] for u in self.units[group]]
            v = np.concatenate(parts) if parts else np.zeros(0)
            self._joined[group, key] = v[np.isfinite(v)]
        return self._joined[group, key]


FLOOR_DRAWS = 200  # random subsets behind a divergence's sampling floor


def js_floor(a: MotionPool, b: MotionPool, group: str, stat: Statistic,
             draws: int = FLOOR_DRAWS, seed: int = 0) -> tuple[float, float, float]:
    """``(median, p10, p90)`` of the divergence that sample size alone gives: as many scenarios
    of ``group`` as the smaller pool has, drawn without replacement from the larger one, against
    the larger pool's other scenarios (two disjoint samples of one distribution). A divergence
    inside it cannot tell the two pools apart. NaN when the larger pool is not larger."""
    small, large = sorted((a.units[group], b.units[group]), key=len)
    if not small or len(small) >= len(large):
        return np.nan, np.nan, np.nan
    counts = np.stack([histogram(u[stat.key], stat.edges) for u in large])  # [scenarios, bins]
    rng = np.random.default_rng(seed)
    drawn = np.zeros((draws, len(large)))
    for row in drawn:
        row[rng.choice(len(large), len(small), replace=False)] = 1.0
    picked = drawn @ counts  # each draw's histogram; its other scenarios': the total less it
    return summary([js_divergence(p, q) for p, q in zip(picked, counts.sum(0) - picked,
                                                         strict=True)])


def motion_summary(pools: dict[str, MotionPool], reference: str) -> list[dict]:
    """Tidy rows per data set, group and statistic: agents, samples, mean, median, p10, p90, the
    Jensen-Shannon divergence (base 2) of its histogram from ``reference``'s and that
    divergence's sampling floor (:func:`js_floor`: median, p10, p90)."""
    rows, ref = [], pools[reference]
    for name, pool in pools.items():
        for g in GROUPS:
            for s in MOTION_STATISTICS:
                v = pool.values(g, s.key)
                med, p10, p90 = summary(v)
                js = (np.nan if name == reference else js_divergence(
                    histogram(v, s.edges), histogram(ref.values(g, s.key), s.edges)))
                floor = (np.nan,) * 3 if name == reference else js_floor(pool, ref, g, s)
                rows.append({"dataset": name, "group": g, "statistic": s.key, "unit": s.unit,
                             "scenarios": pool.scenarios, "agents": pool.agents[g],
                             "samples": len(v), "mean": float(v.mean()) if len(v) else np.nan,
                             "median": med, "p10": p10, "p90": p90,
                             "js": js if np.isnan(js) else round(js, 4),
                             **{f"js_floor_{q}": x if np.isnan(x) else round(x, 4)
                                for q, x in zip(("median", "p10", "p90"), floor, strict=True)},
                             "reference": reference})
    return rows


FIGURE_STATISTICS = tuple(s for s in MOTION_STATISTICS  # CV: at the last horizon only
                          if not s.key.startswith("cv_") or s.key.endswith(f"_{HORIZONS[-1]}s"))


XLABELS = {"cv_distance_8s": "distance", "cv_along_8s": "along, < 0: behind",
           "cv_across_8s": "across"}


def plot_motion(pools: dict[str, MotionPool], path: str) -> None:
    """Two rows of panels per group: the CV distance against the horizon (median, p10-p90 band)
    and the distribution of :data:`FIGURE_STATISTICS`, one line per data set."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing

    cols = 7
    fig, axes = plt.subplots(2 * len(GROUPS), cols, figsize=(3.3 * cols, 2.7 * 2 * len(GROUPS)))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for gi, g in enumerate(GROUPS):
        panels = axes[2 * gi:2 * gi + 2].ravel()
        ax = panels[0]
        for ci, (name, pool) in enumerate(pools.items()):
            c = colours[ci % len(colours)]
            q = np.array([summary(pool.values(g, f"cv_distance_{h}s")) for h in HORIZONS])
            ax.plot(HORIZONS, q[:, 0], "o-", color=c, label=f"{name} (n = {pool.agents[g]})")
            ax.fill_between(HORIZONS, q[:, 1], q[:, 2], color=c, alpha=0.15)
        ax.set_title(f"{GROUP_LABELS[g]}: CV distance", fontsize=9)
        ax.set_xlabel("horizon (s)")
        ax.set_ylabel("distance (m), median, p10-p90")
        ax.legend(fontsize=7, title="n = agents", title_fontsize=7)
        for ax, s in zip(panels[1:], FIGURE_STATISTICS, strict=False):
            for ci, (name, pool) in enumerate(pools.items()):
                h = histogram(pool.values(g, s.key), s.edges)
                share = h / h.sum() if h.sum() else h.astype(float)
                ax.stairs(share, s.edges, color=colours[ci % len(colours)],
                          label=f"{name} (n = {pool.agents[g]})")
            ax.set_title(f"{GROUP_SHORT[g]}: {s.label.removesuffix(' (mean)')}", fontsize=8)
            unit = s.unit or ("events per agent" if s.count else "share of the future")
            name = XLABELS.get(s.key, s.key.replace("_", " "))
            ax.set_xlabel(f"{name} ({unit})")
            ax.set_ylabel(f"share of {'agents' if s.per == 'agent' else 'windows'} per bin")
        for ax in panels[1 + len(FIGURE_STATISTICS):]:
            ax.axis("off")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=90)
    plt.close(fig)
