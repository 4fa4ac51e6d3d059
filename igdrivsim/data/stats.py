"""Scene statistics of a scenario (``igdrivsim stats``, the generator's calibration tests).

Per scenario, at the current step and measured from the SDC, centre to centre: :data:`STATISTICS`.
Per object and step, WOSAC-style samples as fixed-bin histograms (:data:`FEATURES`), whose
Jensen-Shannon divergence says how close two data sets' whole distributions are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from igdrivsim.data.filter import intersecting_objects, sdc_mean_speed, valid_xy
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    DT,
    RG_LANE_BIKE,
    RG_LANE_FREEWAY,
    RG_LANE_SURFACE_STREET,
    RG_ROAD_EDGE_TYPES,
    TYPE_CYCLIST,
    TYPE_PEDESTRIAN,
    TYPE_VEHICLE,
    Scenario,
    decode_scenario_id,
)

NEAR = 6.0  # m: "an object within 6 m" (the paper's circular fields of view are 4-6 m)
STATIC_M, STATIC_MIN_STEPS = 1.0, 10  # never moves: > 10 valid steps, extent < 1 m
ACCEL_LAG = 4  # steps: accelerations are differences over 0.4 s of speeds from 0.1 s positions
LANE_TYPES = (RG_LANE_FREEWAY, RG_LANE_SURFACE_STREET, RG_LANE_BIKE)
MAX_POLYLINE_GAP = 5.0  # m: consecutive same-id points farther apart are not one segment


@dataclass(frozen=True)
class Statistic:
    """A statistic: CSV column, label, unit; a motion statistic (:mod:`.motion_stats`) also has
    histogram ``edges`` (JS divergence, figure), ``per`` ("agent": one value per agent, "step":
    one per valid window) and ``count`` (summarised by its mean: events per agent)."""

    key: str
    label: str
    unit: str = ""
    edges: np.ndarray | None = field(default=None, repr=False, compare=False)
    per: str = "step"
    count: bool = False

    @property
    def title(self) -> str:
        return f"{self.label} ({self.unit})" if self.unit else self.label


STATISTICS = (
    Statistic("objects_50m", "objects within 50 m"),
    Statistic("objects_30m", "objects within 30 m"),
    Statistic("static_share", "share of objects that never move"),
    Statistic("nearest_object", "nearest object at t = 10", "m"),
    Statistic("near_6m_share", "future steps with an object within 6 m"),
    Statistic("lane_length_50m", "lane-centre length within 50 m", "m"),
    Statistic("pedestrians_50m", "pedestrians within 50 m"),
    Statistic("traffic_lights", "traffic lights in the scenario"),
    Statistic("sdc_mean_speed", "SDC mean speed", "m/s"),
    Statistic("sdc_max_accel", "SDC max acceleration (0.4 s)", "m/s^2"),
    Statistic("closest_approach", "closest approach SDC-object", "m"),
    Statistic("tracks", "valid tracks"),
    Statistic("moving_vehicles", "moving vehicles"),
    Statistic("track_seconds", "mean track length", "s"),
    Statistic("sdc_edge_distance", "SDC distance to the road edge at t = 10", "m"),
)

# WOSAC-style per-object-step features: name -> histogram bin edges
FEATURES: dict[str, np.ndarray] = {
    "speed": np.linspace(0.0, 30.0, 61),
    "acceleration": np.linspace(-8.0, 8.0, 65),
    "nearest_object_distance": np.linspace(0.0, 50.0, 101),
    "road_edge_distance": np.linspace(-20.0, 10.0, 61),
}
# The classes the road-edge distance is split by (``road_edge:<class>`` histograms): where a
# data set puts its objects beside the road says more than their pooled distribution. Parked: a
# vehicle with more than STATIC_MIN_STEPS valid steps whose path stays under STATIC_M.
EDGE_CLASSES = ("parked vehicle", "moving vehicle", "pedestrian", "cyclist", "other")


def histogram(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Counts over ``edges``; values beyond the ends go to the outer bins."""
    values = np.clip(values[np.isfinite(values)], edges[0], edges[-1])
    return np.histogram(values, edges)[0].astype(np.int64)


def path_extent(xy: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Diagonal ``[O]`` of each object's box of valid positions (``xy [O, T, 2]``)."""
    lo = np.where(valid[..., None], xy, np.inf).min(1)
    hi = np.where(valid[..., None], xy, -np.inf).max(1)
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(hi - lo, axis=-1)


def _edges(scenario: Scenario) -> tuple[cKDTree | None, np.ndarray]:
    rg = scenario.roadgraph
    sel = np.asarray(rg.valid, bool) & np.isin(np.asarray(rg.type), RG_ROAD_EDGE_TYPES)
    if not sel.any():
        return None, np.zeros((0, 4))
    xy = np.asarray(rg.xyz, np.float64)[sel, :2]
    return cKDTree(xy), np.concatenate([xy, np.asarray(rg.dir, np.float64)[sel, :2]], 1)


def _edge_distance(edges, pts: np.ndarray) -> np.ndarray:
    """Distance to the nearest road-edge point, negative on its inner (left) side."""
    tree, table = edges
    if tree is None or len(pts) == 0:
        return np.full(len(pts), np.nan)
    dist, j = tree.query(pts)
    rel, d = pts - table[j, :2], table[j, 2:]
    cross = d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0]
    return np.where(cross > 0, -dist, dist)


def _lane_length(scenario: Scenario, centre: np.ndarray, radius: float = 50.0) -> float:
    """Length of lane-centre segments with both ends within ``radius`` of ``centre``."""
    rg = scenario.roadgraph
    xy = np.asarray(rg.xyz, np.float64)[:, :2]
    ok = np.asarray(rg.valid, bool) & np.isin(np.asarray(rg.type), LANE_TYPES)
    ok &= np.linalg.norm(xy - centre, axis=1) <= radius
    ids = np.asarray(rg.id)
    seg = ok[:-1] & ok[1:] & (ids[:-1] == ids[1:])
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    return float(step[seg & (step <= MAX_POLYLINE_GAP)].sum())


def scene_statistics(scenario: Scenario) -> tuple[dict, dict[str, np.ndarray]]:
    """``(row, histograms)`` of one unbatched scenario: the :data:`STATISTICS`, ``scenario_id``
    and ``kept`` (the paper's filter); the :data:`FEATURES` counts over valid objects and steps,
    and the road-edge counts per :data:`EDGE_CLASSES` (``road_edge:<class>``)."""
    md = scenario.metadata
    valid, xy = valid_xy(scenario)
    types = np.asarray(md.object_type)
    sdc = int(np.argmax(np.asarray(md.is_sdc)))
    n, steps = valid.shape
    others = valid.any(1) & (np.arange(n) != sdc)

    dist = np.linalg.norm(xy - xy[sdc][None], axis=-1)  # [O, T]
    both = valid & valid[sdc][None]
    both[sdc] = False
    dist = np.where(both, dist, np.inf)
    now = dist[:, CURRENT_INDEX]
    future = dist[:, CURRENT_INDEX + 1:]
    future_ok = valid[sdc, CURRENT_INDEX + 1:]
    counted = valid.sum(1) > STATIC_MIN_STEPS
    static = counted & others & (path_extent(xy, valid) < STATIC_M)
    moving = counted & others & ~static
    step = np.linalg.norm(np.diff(xy, axis=1), axis=-1) / DT  # [O, T-1], from 0.1 s positions
    step_ok = valid[:, 1:] & valid[:, :-1]
    acc = (step[:, ACCEL_LAG:] - step[:, :-ACCEL_LAG]) / (ACCEL_LAG * DT)
    acc_ok = step_ok[:, ACCEL_LAG:] & step_ok[:, :-ACCEL_LAG]
    sdc_acc = np.abs(acc[sdc][acc_ok[sdc]])
    edges = _edges(scenario)
    sdc_now = xy[sdc, CURRENT_INDEX]
    row = {
        "scenario_id": decode_scenario_id(scenario.scenario_id),
        "objects_50m": int((now <= 50).sum()),
        "objects_30m": int((now <= 30).sum()),
        "static_share": float(static.sum() / max(counted[others].sum(), 1)),
        "nearest_object": float(now.min()) if np.isfinite(now).any() else np.nan,
        "near_6m_share": float(((future <= NEAR).any(0) & future_ok).sum()
                               / max(future_ok.sum(), 1)),
        "lane_length_50m": _lane_length(scenario, sdc_now),
        "pedestrians_50m": int(((now <= 50) & (types == TYPE_PEDESTRIAN)).sum()),
        "traffic_lights": int(np.asarray(scenario.traffic_lights.valid, bool).any(-1).sum()),
        "sdc_mean_speed": sdc_mean_speed(scenario),
        "sdc_max_accel": float(sdc_acc.max()) if len(sdc_acc) else np.nan,
        "closest_approach": float(dist.min()) if np.isfinite(dist).any() else np.nan,
        "tracks": int(valid.any(1).sum()),
        "moving_vehicles": int((moving & (types == TYPE_VEHICLE)).sum()),
        "track_seconds": float(valid.sum(1)[valid.any(1)].mean() * DT),
        "sdc_edge_distance": float(_edge_distance(edges, sdc_now[None])[0]),
        "kept": bool(intersecting_objects(scenario).any() and sdc_mean_speed(scenario) >= 0.7),
    }
    nearest = np.full(valid.shape, np.nan)
    for t in range(steps):
        idx = np.flatnonzero(valid[:, t])
        if len(idx) > 1:
            d, _ = cKDTree(xy[idx, t]).query(xy[idx, t], k=2)
            nearest[idx, t] = d[:, 1]
    edge = np.full(valid.shape, np.nan)
    edge[valid] = _edge_distance(edges, xy[valid])
    vehicle = types == TYPE_VEHICLE
    parked = vehicle & counted & (path_extent(xy, valid) < STATIC_M)  # the SDC included
    classes = dict(zip(EDGE_CLASSES, (parked, vehicle & ~parked, types == TYPE_PEDESTRIAN,
                                      types == TYPE_CYCLIST), strict=False))
    classes["other"] = ~np.any(list(classes.values()), 0)
    by_class = {f"road_edge:{c}": histogram(edge[mask], FEATURES["road_edge_distance"])
                for c, mask in classes.items()}  # the classes cover every object once
    return row, {
        "speed": histogram(step[step_ok], FEATURES["speed"]),
        "acceleration": histogram(acc[acc_ok], FEATURES["acceleration"]),
        "nearest_object_distance": histogram(nearest[valid], FEATURES["nearest_object_distance"]),
        "road_edge_distance": sum(by_class.values()),
        **by_class,
    }


def js_divergence(p: np.ndarray, q: np.ndarray) -> float:
    """Jensen-Shannon divergence (base 2, in [0, 1]) of two histograms; NaN if one is empty."""
    from scipy.spatial.distance import jensenshannon  # heavy: scipy is needed only here

    if p.sum() == 0 or q.sum() == 0:
        return float("nan")
    return float(jensenshannon(p, q, base=2) ** 2)


def summary(values) -> tuple[float, float, float]:
    """``(median, p10, p90)`` of the finite values (NaN when there are none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if not len(v):
        return (np.nan,) * 3
    return tuple(float(x) for x in np.percentile(v, [50, 10, 90]))
