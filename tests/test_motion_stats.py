"""Motion statistics (igdrivsim.data.motion_stats) on hand-made trajectories with known answers.
NumPy only: no JAX compile, well under a second."""

from __future__ import annotations

import numpy as np
import pytest

from igdrivsim.data.motion_stats import (
    AGENT_KEYS,
    GROUPS,
    HORIZONS,
    MOTION_STATISTICS,
    STEP_KEYS,
    LaneMap,
    Motion,
    MotionPool,
    agent_motion,
    js_floor,
    motion_statistics,
    motion_summary,
)
from igdrivsim.data.scenario import NUM_STEPS, Capacities, empty_scenario

T = np.arange(NUM_STEPS) * 0.1


def lanes(*ys: float, step: float = 0.5) -> LaneMap:
    """Straight lanes along +x at the given y, one polyline id each (1, 2, ...)."""
    x = np.arange(-50.0, 500.0, step)
    xy = np.concatenate([np.stack([x, np.full_like(x, y)], 1) for y in ys])
    return LaneMap(xy, np.repeat(np.arange(1, len(ys) + 1), len(x)))


def motion(x, y, yaw, vx=None, vy=None, lane_map=None, valid=None):
    xy = np.stack([np.broadcast_to(x, T.shape), np.broadcast_to(y, T.shape)], -1)
    vel = np.stack([np.broadcast_to(0.0 if vx is None else vx, T.shape),
                    np.broadcast_to(0.0 if vy is None else vy, T.shape)], -1)
    valid = np.ones(NUM_STEPS, bool) if valid is None else valid
    return agent_motion(xy, np.broadcast_to(yaw, T.shape), vel, valid, lane_map)


def test_constant_velocity_is_zero_distance():
    row, s = motion(3.0 + 8.0 * T, 2.0, 0.0, vx=8.0, lane_map=lanes(2.0))
    for h in HORIZONS:
        for k in ("distance", "along", "across"):
            assert row[f"cv_{k}_{h}s"] == pytest.approx(0.0, abs=1e-9)
    assert s["speed"] == pytest.approx(8.0) and s["acceleration"] == pytest.approx(0.0, abs=1e-9)
    assert s["jerk"] == pytest.approx(0.0, abs=1e-9)
    assert s["yaw_rate"] == pytest.approx(0.0) and s["curvature"] == pytest.approx(0.0)
    assert s["lane_offset"] == pytest.approx(0.0, abs=1e-6) and len(s["lane_offset"]) == NUM_STEPS
    assert s["lane_offset_rate"] == pytest.approx(0.0, abs=1e-6)
    assert row["stopped_share"] == 0 and row["turns"] == 0 and row["lane_changes"] == 0


def test_constant_acceleration_is_along_track_only():
    a, v0, yaw = 1.5, 2.0, 0.7  # heading 0.7 rad: along/across follow the heading, not x
    u = v0 * T + a * T**2 / 2
    row, s = motion(u * np.cos(yaw), u * np.sin(yaw), yaw, vx=(v0 + a * T) * np.cos(yaw),
                    vy=(v0 + a * T) * np.sin(yaw))
    for h in HORIZONS:
        assert row[f"cv_along_{h}s"] == pytest.approx(a * h**2 / 2, rel=1e-4)
        assert row[f"cv_across_{h}s"] == pytest.approx(0.0, abs=1e-4)
        assert row[f"cv_distance_{h}s"] == pytest.approx(a * h**2 / 2, rel=1e-4)
    assert s["acceleration"] == pytest.approx(a, rel=1e-6)
    assert s["jerk"] == pytest.approx(0.0, abs=1e-6)
    assert np.isnan(row["lane_changes"]) and len(s["lane_offset"]) == 0  # no lanes: undefined


def test_circle_yaw_rate_and_curvature():
    radius, v = 20.0, 5.0
    phi = v * T / radius
    row, s = motion(radius * np.sin(phi), radius * (1 - np.cos(phi)), phi,
                    vx=v * np.cos(phi), vy=v * np.sin(phi))
    assert s["yaw_rate"] == pytest.approx(v / radius, rel=1e-9)
    assert s["curvature"] == pytest.approx(1 / radius, rel=1e-3)  # chord speed over 0.4 s
    assert s["speed"] == pytest.approx(v, rel=1e-3)
    # 8 s on the circle: 2 rad of heading, far from the straight line; it curves left
    assert row["cv_across_8s"] > 10 and row["cv_along_8s"] < 0 and row["turns"] == 1


def test_stopped_agent():
    row, s = motion(5.0, 1.0, 0.3)
    assert row["stopped_share"] == 1 and row["turns"] == 0
    assert row["cv_distance_8s"] == 0 and s["speed"] == pytest.approx(0.0)
    assert len(s["yaw_rate"]) == 0 and len(s["curvature"]) == 0  # only above 1 m/s


def test_lateral_offset_step_is_one_lane_change():
    lane_map = lanes(0.0, 3.5)
    y = np.where(np.arange(NUM_STEPS) < 50, 0.0, 3.5)
    row, s = motion(10 * T, y, 0.0, vx=10.0, lane_map=lane_map)
    assert row["lane_changes"] == 1
    assert s["lane_offset"] == pytest.approx(0.0, abs=1e-6)
    # a smooth change over 3 s and a change back after 2 s: two
    y = np.clip((T - 2.0) / 3.0, 0, 1) * 3.5 - np.clip((T - 7.0) / 1.5, 0, 1) * 3.5
    assert motion(10 * T, y, 0.0, vx=10.0, lane_map=lane_map)[0]["lane_changes"] == 2
    # jitter across the boundary (there and back within 1 s) is no lane change
    y = np.where(np.arange(NUM_STEPS) % 10 < 3, 1.80, 1.70)
    assert motion(10 * T, y, 0.0, vx=10.0, lane_map=lane_map)[0]["lane_changes"] == 0
    # a successor polyline (same line, new id) is no lane change either
    x = np.arange(-50.0, 500.0, 0.5)
    chain = LaneMap(np.stack([x, 0 * x], 1), np.where(x < 40, 1, 2))
    assert motion(10 * T, 0.0, 0.0, vx=10.0, lane_map=chain)[0]["lane_changes"] == 0


def test_lane_offset_sign_and_heading():
    row, s = motion(10 * T, 0.6, 0.0, vx=10.0, lane_map=lanes(0.0, 3.5))
    assert s["lane_offset"] == pytest.approx(0.6, abs=1e-6)  # left of the lane: positive
    # driving against every lane: no aligned lane centre, no offset
    _, s = motion(-10 * T, 0.6, np.pi, vx=-10.0, lane_map=lanes(0.0))
    assert len(s["lane_offset"]) == 0
    # a slow drift of 0.5 m/s towards the left
    _, s = motion(10 * T, 0.5 * T - 1.0, 0.0, vx=10.0, lane_map=lanes(0.0))
    assert s["lane_offset_rate"] == pytest.approx(0.5, rel=1e-6)


def test_ninety_degree_turn_is_one_turn():
    radius, v = 10.0, 5.0
    t_arc = np.pi / 2 * radius / v  # 3.14 s
    u = np.clip(T - 2.0, 0, t_arc)  # straight 2 s, quarter circle, then straight along +y
    phi = v * u / radius
    after = np.clip(T - 2.0 - t_arc, 0, None) * v
    x = np.minimum(T, 2.0) * v + radius * np.sin(phi)
    y = radius * (1 - np.cos(phi)) + after
    row, _ = motion(x, y, phi, vx=v * np.cos(phi), vy=v * np.sin(phi))
    assert row["turns"] == 1
    # a 30-degree bend is no turn
    phi = np.minimum(phi, np.radians(30))
    step = np.stack([np.cos(phi), np.sin(phi)], 1) * v * 0.1
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(step, 0)[:-1]])
    assert motion(xy[:, 0], xy[:, 1], phi, vx=v * np.cos(phi), vy=v * np.sin(phi))[0][
        "turns"] == 0


def scene():
    """SDC at 8 m/s along a lane; a car at 6 m/s on the lane beside it; a parked car; a walker."""
    s = empty_scenario(Capacities(max_objects=4, max_roadgraph_points=2 * 1100,
                                  max_traffic_lights=1))
    x = np.stack([8 * T, 6 * T + 5, 0 * T + 30, 0.8 * T])
    y = np.stack([0 * T, 0 * T + 3.5, 0 * T + 7, 0 * T - 6])
    vx = np.stack([0 * T + 8, 0 * T + 6, 0 * T, 0 * T + 0.8])
    f32 = np.float32
    tr = s.trajectory.replace(x=x.astype(f32), y=y.astype(f32), vel_x=vx.astype(f32),
                              valid=np.ones((4, NUM_STEPS), bool))
    md = s.metadata.replace(is_sdc=np.arange(4) == 0, valid=np.ones(4, bool),
                            object_type=np.array([1, 1, 1, 2], np.int32))
    lane_map = lanes(0.0, 3.5)
    n = len(lane_map.xy)
    xyz = np.concatenate([lane_map.xy, np.zeros((n, 1))], 1)
    rg = s.roadgraph.replace(xyz=xyz.astype(f32), type=np.full(n, 2, np.int32),
                             id=lane_map.ids.astype(np.int32), valid=np.ones(n, bool))
    return s.replace(trajectory=tr, metadata=md, roadgraph=rg)


def test_scenario_groups_pool_and_divergence():
    m = motion_statistics(scene())
    assert [(a["group"], a["object"]) for a in m.agents] == [("sdc", 0), ("others", 1)]
    assert m.samples["sdc"]["speed"] == pytest.approx(8.0, rel=1e-5)
    assert m.samples["others"]["lane_offset"] == pytest.approx(0.0, abs=1e-5)
    pool = MotionPool()
    pool.add(m)
    pool.add(Motion(m.agents, m.samples))
    assert pool.scenarios == 2 and pool.agents == {"sdc": 2, "others": 2}
    rows = motion_summary({"a": pool, "b": pool}, reference="b")
    assert len(rows) == 2 * 2 * len(MOTION_STATISTICS)
    speed = next(r for r in rows if r["dataset"] == "a" and r["group"] == "sdc"
                 and r["statistic"] == "speed")
    assert speed["median"] == pytest.approx(8.0, rel=1e-5) and speed["js"] == 0.0
    assert np.isnan(next(r for r in rows if r["dataset"] == "b")["js"])


def speed_pool(scenarios: int, mean: float, seed: int) -> MotionPool:
    """One SDC per scenario whose 40 speed samples are normal around ``mean`` (other keys 0)."""
    rng = np.random.default_rng(seed)
    pool = MotionPool()
    for _ in range(scenarios):
        samples = {g: dict.fromkeys(STEP_KEYS, np.zeros(0)) for g in GROUPS}
        samples["sdc"] = {**samples["sdc"], "speed": rng.normal(mean, 3.0, 40).clip(0, 30)}
        pool.add(Motion([{"group": "sdc", "object": 0, **dict.fromkeys(AGENT_KEYS, 0.0)}],
                        samples))
    return pool


def test_divergence_floor_separates_sample_size_from_a_real_difference():
    speed = next(s for s in MOTION_STATISTICS if s.key == "speed")
    big, same, shifted = speed_pool(200, 10.0, 0), speed_pool(10, 10.0, 1), speed_pool(10, 16.0, 2)
    rows = motion_summary({"same": same, "shifted": shifted, "big": big}, reference="big")
    row = {r["dataset"]: r for r in rows if r["group"] == "sdc" and r["statistic"] == "speed"}
    floor = js_floor(same, big, "sdc", speed)
    assert floor == js_floor(big, same, "sdc", speed)  # seeded, and symmetric in its pools
    assert 0.0 < floor[1] < floor[0] < floor[2]
    assert row["same"]["js_floor_median"] == pytest.approx(floor[0], abs=1e-4)
    assert floor[1] <= row["same"]["js"] <= floor[2]  # the same distribution: inside the floor
    assert row["shifted"]["js"] > 2 * row["shifted"]["js_floor_p90"]  # a real shift: far above
    assert np.isnan(js_floor(same, same, "sdc", speed)[0])  # equal sizes: no larger pool
    assert np.isnan(row["big"]["js_floor_median"])  # the reference itself
