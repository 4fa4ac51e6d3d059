"""Metrics on constructed geometry: box overlap, road-edge signed distance, offroad, divergence."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    RG_ROAD_EDGE_BOUNDARY,
    RG_ROAD_EDGE_MEDIAN,
    Capacities,
    empty_scenario,
)
from igdrivsim.simulator import SimParams, reset
from igdrivsim.simulator.metrics import (
    StepMetrics,
    boxes_overlap,
    mean_log_divergence,
    reward,
    signed_distance_point,
    signed_distance_segment,
    step_metrics,
)
from igdrivsim.simulator.roadgraph import road_edges_from_roadgraph
from igdrivsim.simulator.toy import add_polyline, straight_road

PARAMS = SimParams()
SEGMENT = SimParams(offroad_method="segment")
_reset = jax.jit(reset, static_argnums=1)
_metrics = jax.jit(step_metrics, static_argnums=1)
_sd_point = jax.jit(signed_distance_point)
_sd_segment = jax.jit(signed_distance_segment)
_road_edges = jax.jit(road_edges_from_roadgraph)


def overlaps(a, b):
    return bool(boxes_overlap(*[jnp.float32(v) for v in (*a, *b)]))


# ---------------------------------------------------------------- box overlap (SAT)
def test_touching_boxes_do_not_overlap_but_a_centimetre_more_does():
    a = (0.0, 0.0, 4.0, 2.0, 0.0)
    assert not overlaps(a, (4.0, 0.0, 4.0, 2.0, 0.0))  # end to end, exactly touching
    assert not overlaps(a, (0.0, 2.0, 4.0, 2.0, 0.0))  # side by side, exactly touching
    assert overlaps(a, (3.99, 0.0, 4.0, 2.0, 0.0))
    assert not overlaps(a, (4.01, 0.0, 4.0, 2.0, 0.0))
    assert overlaps(a, (0.0, -1.99, 4.0, 2.0, 0.0))


def test_rotated_box_corner_just_in_and_just_out():
    # A 2x2 square rotated by 45 deg has its corner sqrt(2) from its centre along x.
    a = (0.0, 0.0, 4.0, 2.0, 0.0)  # front face at x = 2
    r = np.sqrt(2.0)
    assert overlaps(a, (2.0 + r - 0.01, 0.0, 2.0, 2.0, np.pi / 4))
    assert not overlaps(a, (2.0 + r + 0.01, 0.0, 2.0, 2.0, np.pi / 4))
    # Separated only along a rotated box's own axis (its corners clear the axis-aligned box).
    assert not overlaps((0.0, 0.0, 2.0, 2.0, 0.0), (1.1, 1.1, 2.0, 0.2, -np.pi / 4))
    assert overlaps((0.0, 0.0, 2.0, 2.0, 0.0), (1.05, 1.05, 2.0, 0.2, -np.pi / 4))


def test_nested_boxes_overlap_both_ways():
    big, small = (1.0, 2.0, 10.0, 6.0, 0.3), (1.5, 2.2, 1.0, 0.5, -1.0)
    assert overlaps(big, small) and overlaps(small, big)
    assert overlaps(big, big)


def _sat_reference(a, b):
    """Generic SAT on corner projections (NumPy, float64)."""
    def corners(x, y, length, width, yaw):
        u = np.array([np.cos(yaw), np.sin(yaw)]) * length / 2
        v = np.array([-np.sin(yaw), np.cos(yaw)]) * width / 2
        return np.array([x, y]) + np.array([u + v, -u + v, -u - v, u - v])
    ca, cb = corners(*a), corners(*b)
    for yaw in (a[4], b[4]):
        for axis in ([np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]):
            pa, pb = ca @ axis, cb @ axis
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def test_overlap_matches_a_generic_reference_on_random_boxes():
    rng = np.random.default_rng(0)
    a = np.stack([rng.uniform(-4, 4, 300), rng.uniform(-4, 4, 300), rng.uniform(1, 6, 300),
                  rng.uniform(0.5, 3, 300), rng.uniform(-np.pi, np.pi, 300)], -1)
    b = np.stack([rng.uniform(-4, 4, 300), rng.uniform(-4, 4, 300), rng.uniform(1, 6, 300),
                  rng.uniform(0.5, 3, 300), rng.uniform(-np.pi, np.pi, 300)], -1)
    got = np.asarray(boxes_overlap(*jnp.asarray(a.T, jnp.float32), *jnp.asarray(b.T, jnp.float32)))
    want = np.array([_sat_reference(a[i], b[i]) for i in range(300)])
    assert 50 < want.sum() < 250  # both outcomes well represented
    # float32 vs float64: allow disagreement only for near-touching pairs (none expected here)
    assert (got == want).mean() >= 0.99


# ---------------------------------------------------------------- scenario helpers
def road_state(extra_edges=None, half_width=5.0):
    """Reset state of the toy straight road (edges at y = +-half_width)."""
    sc = straight_road(half_width=half_width)
    if extra_edges is not None:
        extra_edges(sc)
    return _reset(sc, PARAMS)


def place_sdc(state, x, y, yaw=0.0):
    """Put the simulated SDC at a pose at the current step."""
    t = int(state.timestep)
    s = state.sdc
    return state.replace(sdc=s.replace(x=s.x.at[t].set(x), y=s.y.at[t].set(y),
                                       yaw=s.yaw.at[t].set(yaw)))


# ---------------------------------------------------------------- overlap(state)
def test_overlap_against_other_valid_objects_only():
    st = road_state()
    assert not bool(_metrics(st, PARAMS).overlap)  # the car ahead is 20 m away
    x_ahead = float(st.log.x[1, CURRENT_INDEX])
    hit = place_sdc(st, x_ahead - 4.4, 0.0)  # 10 cm into its back bumper
    assert bool(_metrics(hit, PARAMS).overlap)
    miss = place_sdc(st, x_ahead - 4.6, 0.0)
    assert not bool(_metrics(miss, PARAMS).overlap)
    gone = hit.replace(log=hit.log.replace(valid=hit.log.valid.at[1].set(False)))
    assert not bool(_metrics(gone, PARAMS).overlap)


# ---------------------------------------------------------------- offroad
@pytest.mark.parametrize("params", [PARAMS, SEGMENT], ids=["point", "segment"])
def test_corners_just_inside_and_just_outside_both_edges(params):
    st = road_state()  # SDC 4.5 x 2; edges at y = -5 (runs +x) and y = +5 (runs -x)
    for y, off in ((3.99, False), (4.01, True), (-3.99, False), (-4.01, True), (0.0, False)):
        assert bool(_metrics(place_sdc(st, 5.3, y), params).offroad) == off, y
    # rotated by 90 deg: half length 2.25 across the road
    assert not bool(_metrics(place_sdc(st, 5.3, 2.74, np.pi / 2), params).offroad)
    assert bool(_metrics(place_sdc(st, 5.3, 2.76, np.pi / 2), params).offroad)
    assert bool(_metrics(place_sdc(st, 5.3, 30.0), params).offroad)  # far off the road


def _median_island(sc):
    """A median island, x in [0, 20], y in [-2, 2], closed loop with the road on its left
    (clockwise), 1 m spacing."""
    xs = np.arange(0.0, 21.0)
    ys = np.arange(-2.0, 2.01, 1.0)
    loop = np.concatenate([
        np.stack([np.zeros_like(ys), ys], 1),  # up the west side
        np.stack([xs[1:], np.full_like(xs[1:], 2.0)], 1),  # east along the top
        np.stack([np.full(len(ys) - 1, 20.0), ys[::-1][1:]], 1),  # down the east side
        np.stack([xs[::-1][1:], np.full_like(xs[1:], -2.0)], 1),  # west along the bottom
    ])
    add_polyline(sc, 500, loop.astype(np.float32), RG_ROAD_EDGE_MEDIAN, 9)


@pytest.mark.parametrize("params", [PARAMS, SEGMENT], ids=["point", "segment"])
def test_both_sides_of_a_median(params):
    st = road_state(_median_island, half_width=8.0)
    # lanes either side of the island: on road; on the island: offroad
    assert not bool(_metrics(place_sdc(st, 10.0, 3.05), params).offroad)
    assert not bool(_metrics(place_sdc(st, 10.0, -3.05, np.pi), params).offroad)
    assert bool(_metrics(place_sdc(st, 10.0, 2.95), params).offroad)
    assert bool(_metrics(place_sdc(st, 10.0, -2.95, np.pi), params).offroad)
    assert bool(_metrics(place_sdc(st, 10.0, 0.0), params).offroad)


def _edges(polylines):
    """RoadEdges of an unbatched roadgraph made of ``(xy, type)`` polylines."""
    sc = empty_scenario(Capacities(max_objects=2, max_roadgraph_points=64))
    i = 0
    for k, (xy, t) in enumerate(polylines):
        i = add_polyline(sc, i, np.asarray(xy, np.float32), t, k)
    return _road_edges(sc.roadgraph)


def test_point_rule_false_offroad_at_a_convex_corner_segment_rule_correct():
    # Island [0, 1]^2 traversed clockwise (road outside, on the left), 0.5 m spacing.
    loop = [(0, 0), (0, 0.5), (0, 1), (0.5, 1), (1, 1), (1, 0.5), (1, 0), (0.5, 0), (0, 0)]
    edges = _edges([(loop, RG_ROAD_EDGE_MEDIAN)])
    # Above the top side, near the corner (1, 1): nearest sample is the corner, whose stored
    # direction points down the east side, so the point rule calls it outside the road.
    px, py = jnp.asarray([0.97]), jnp.asarray([1.5])
    assert float(_sd_point(px, py, edges)[0]) > 0
    seg = float(_sd_segment(px, py, edges)[0])
    assert seg == pytest.approx(-0.5, abs=1e-5)
    # In the corner's own region, both rules agree (on road), and inside both say offroad.
    px, py = jnp.asarray([1.3, 0.5, 0.9]), jnp.asarray([1.4, 0.5, 0.95])
    np.testing.assert_allclose(_sd_segment(px, py, edges),
                               [-0.5, 0.5, 0.05], atol=1e-5)
    assert np.all(np.sign(_sd_point(px, py, edges)) == [-1, 1, 1])


def test_segment_distance_between_samples_and_on_a_straight_edge():
    edges = _edges([([(0, 0), (10, 0)], RG_ROAD_EDGE_BOUNDARY)])  # interior: y > 0
    px, py = jnp.asarray([5.0, 5.0, -3.0]), jnp.asarray([2.0, -1.5, 4.0])
    np.testing.assert_allclose(_sd_segment(px, py, edges), [-2.0, 1.5, -5.0],
                               atol=1e-5)
    # the point rule measures to the nearest sample, here 5 m along the edge
    np.testing.assert_allclose(np.abs(_sd_point(px, py, edges)),
                               np.hypot([5.0, 5.0, 3.0], [2.0, 1.5, 4.0]), atol=1e-5)


def test_no_road_edges_means_never_offroad():
    sc = straight_road()
    sc.roadgraph.valid[200:] = False  # keep only the centre line
    st = _reset(sc, PARAMS)
    assert not bool(_metrics(place_sdc(st, 0.0, 50.0), PARAMS).offroad)


# ---------------------------------------------------------------- divergence, reward, aggregation
def test_log_divergence_and_validity():
    st = road_state()
    m = _metrics(st, PARAMS)
    assert float(m.log_divergence) == 0.0 and bool(m.valid)
    x0 = float(st.sdc.x[CURRENT_INDEX])
    m = _metrics(place_sdc(st, x0 + 3.0, 4.0), PARAMS)
    assert float(m.log_divergence) == pytest.approx(5.0, abs=1e-5)
    gone = st.replace(sdc=st.sdc.replace(valid=st.sdc.valid.at[CURRENT_INDEX].set(False)))
    m = _metrics(place_sdc(gone, 0.0, 30.0), PARAMS)
    assert not bool(m.valid) and not bool(m.offroad) and float(m.log_divergence) == 0.0


def test_reward_and_mean_log_divergence():
    ov = jnp.asarray([[False, True, False], [False, False, False]])
    off = jnp.asarray([[True, True, False], [False, False, False]])
    div = jnp.asarray([[0.5, 2.0, 9.0], [1.0, 3.0, 0.0]])
    valid = jnp.asarray([[True, True, False], [True, True, True]])
    m = StepMetrics(overlap=ov, offroad=off, log_divergence=div, valid=valid)
    np.testing.assert_array_equal(reward(m), [[-1, -2, 0], [0, 0, 0]])
    np.testing.assert_allclose(mean_log_divergence(m), [1.25, 4.0 / 3.0])


def _reference_signed_distances(px, py, edges):
    """NumPy argmin version of both rules (float64), for random-point checks."""
    xy, nxt = np.asarray(edges.xy, np.float64), np.asarray(edges.next_xy, np.float64)
    dirs, ok = np.asarray(edges.dir, np.float64), np.asarray(edges.valid)
    xy, nxt, dirs = xy[ok], nxt[ok], dirs[ok]
    bs, be = np.asarray(edges.bis_start)[ok], np.asarray(edges.bis_end)[ok]
    point, segment = [], []
    for p in np.stack([px, py], -1):
        r = p - xy
        j = np.argmin((r * r).sum(-1))
        c = r[j, 0] * dirs[j, 1] - r[j, 1] * dirs[j, 0]
        point.append(np.hypot(*r[j]) * (1 if c > 0 else -1))
        s = nxt - xy
        len2 = (s * s).sum(-1)
        u = np.clip((r * s).sum(-1) / np.maximum(len2, 1e-12), 0, 1)
        q = r - u[:, None] * s
        j = np.argmin((q * q).sum(-1))
        d = bs[j] if u[j] <= 0 else be[j] if (u[j] >= 1 and len2[j] > 0) else s[j]
        c = q[j, 0] * d[1] - q[j, 1] * d[0]
        segment.append(np.hypot(*q[j]) * (1 if c > 0 else -1))
    return np.array(point), np.array(segment)


def test_signed_distances_match_an_argmin_reference_on_random_points():
    square = [(0, 0), (0, 4), (3, 4), (3, 0), (0, 0)]  # clockwise island, 1-4 m segments
    edges = _edges([(square, RG_ROAD_EDGE_MEDIAN),
                    ([(-5, -3), (-1, -3.5), (4, -3), (8, -2)], RG_ROAD_EDGE_BOUNDARY)])
    rng = np.random.default_rng(3)
    px, py = rng.uniform(-6, 9, 64).astype(np.float32), rng.uniform(-5, 6, 64).astype(np.float32)
    want_point, want_segment = _reference_signed_distances(px, py, edges)
    np.testing.assert_allclose(_sd_point(jnp.asarray(px), jnp.asarray(py), edges), want_point,
                               atol=1e-4)
    np.testing.assert_allclose(_sd_segment(jnp.asarray(px), jnp.asarray(py), edges),
                               want_segment, atol=1e-4)
