"""Dynamics, discretiser, reset/step semantics, the roadgraph crop and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    NUM_STEPS,
    RG_ROAD_EDGE_TYPES,
    encode_scenario_id,
)
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.simulator import (
    SimParams,
    current_objects,
    delta_global,
    delta_local,
    discretize,
    inverse_delta_global,
    inverse_delta_local,
    reset,
    sdc_yaw_rate,
    step,
    undiscretize,
)
from igdrivsim.simulator.roadgraph import select_road_edges
from igdrivsim.simulator.toy import straight_road

PARAMS = SimParams()
_reset = jax.jit(reset, static_argnums=1)
_step = jax.jit(step, static_argnums=2)


@pytest.fixture(scope="module")
def state():
    return _reset(straight_road(), PARAMS)


@pytest.mark.parametrize("forward,inverse", [(delta_local, inverse_delta_local),
                                              (delta_global, inverse_delta_global)])
def test_inverse_dynamics_recovers_the_action(forward, inverse):
    rng = np.random.default_rng(0)
    pose = rng.uniform(-50, 50, (3, 64)).astype(np.float32)
    pose[2] = rng.uniform(-np.pi, np.pi, 64)
    action = rng.uniform([-6, -6, -np.pi], [6, 6, np.pi], (64, 3)).astype(np.float32)
    x1, y1, yaw1, vx, vy = forward(*pose, action)
    np.testing.assert_allclose(inverse(*pose, x1, y1, yaw1), action, atol=2e-4)
    # velocity is the displacement over one step (0.1 s)
    np.testing.assert_allclose(vx, (x1 - pose[0]) / 0.1, atol=2e-2)
    np.testing.assert_allclose(vy, (y1 - pose[1]) / 0.1, atol=2e-2)


def test_delta_local_moves_in_the_ego_frame():
    x, y, yaw, _, _ = delta_local(jnp.float32(1.0), jnp.float32(2.0), jnp.float32(np.pi / 2),
                                  jnp.asarray([1.0, 0.5, 0.1]))
    np.testing.assert_allclose([x, y, yaw], [0.5, 3.0, np.pi / 2 + 0.1], atol=1e-6)


def test_discretiser_levels_bounds_and_round_trip():
    idx = discretize(jnp.asarray([[0.0, 0.0, 0.0], [-6.0, 6.0, -np.pi], [100.0, -100.0, 9.0]]))
    np.testing.assert_array_equal(idx, [[128, 128, 128], [0, 256, 0], [256, 0, 256]])
    step_size = np.asarray(undiscretize(jnp.asarray([1, 1, 1]))) - np.asarray(
        undiscretize(jnp.asarray([0, 0, 0])))
    np.testing.assert_allclose(step_size, [12 / 256, 12 / 256, 2 * np.pi / 256], rtol=1e-5)
    a = np.random.default_rng(1).uniform([-6, -6, -np.pi], [6, 6, np.pi], (200, 3))
    err = np.abs(np.asarray(undiscretize(discretize(jnp.asarray(a, jnp.float32)))) - a)
    assert np.all(err <= step_size / 2 + 1e-5)
    np.testing.assert_array_equal(discretize(jnp.asarray([np.nan, 1.0, 1.0])), [128] * 3)


def test_reset_replays_the_warm_up_and_step_follows_the_log(state):
    assert int(state.timestep) == CURRENT_INDEX
    sdc = state.sdc
    np.testing.assert_array_equal(sdc.valid, np.arange(NUM_STEPS) <= CURRENT_INDEX)
    np.testing.assert_allclose(sdc.x[:CURRENT_INDEX + 1], state.log.x[0, :CURRENT_INDEX + 1])
    nxt = _step(state, jnp.asarray([2.0, 0.5, 0.0]), PARAMS)  # SDC faces +x
    assert int(nxt.timestep) == CURRENT_INDEX + 1
    obj = current_objects(nxt)
    np.testing.assert_allclose([obj.x[0], obj.y[0]], [float(sdc.x[10]) + 2.0, 0.5], atol=1e-5)
    np.testing.assert_allclose([obj.vel_x[0], obj.vel_y[0]], [20.0, 5.0], atol=1e-3)
    # other objects replay their log
    np.testing.assert_allclose(obj.x[1], state.log.x[1, CURRENT_INDEX + 1])


def test_yaw_rate_is_the_last_heading_change_and_zero_at_the_first_step(state):
    from igdrivsim.observation import get_setting, observe

    assert float(sdc_yaw_rate(state)) == pytest.approx(0.0, abs=1e-6)  # the straight log
    turned = _step(state, jnp.asarray([1.0, 0.0, 0.05]), PARAMS)
    assert float(sdc_yaw_rate(turned)) == pytest.approx(0.5, rel=1e-4)
    back = turned.replace(sdc=turned.sdc.replace(yaw=turned.sdc.yaw.at[10].set(3.1)
                                                 .at[11].set(-3.1)))
    assert float(sdc_yaw_rate(back)) == pytest.approx((2 * np.pi - 6.2) / 0.1, rel=1e-3)
    assert float(sdc_yaw_rate(state.replace(timestep=jnp.int32(0)))) == 0.0
    key = jax.random.key(0)
    obs = observe(turned, get_setting("full"), key, key)
    np.testing.assert_allclose(obs.sdc_yaw_rate, [0.5], rtol=1e-4)


def test_actions_are_clipped_and_nan_is_rejected_or_masked(state):
    far = _step(state, jnp.asarray([100.0, 0.0, 0.0]), PARAMS)
    assert float(current_objects(far).x[0] - state.sdc.x[10]) == pytest.approx(6.0, abs=1e-4)
    with pytest.raises(DataError, match="non-finite"):
        step(state, np.asarray([np.nan, 0.0, 0.0], np.float32), PARAMS)
    masked = _step(state, jnp.asarray([jnp.nan, 1.0, 0.0]), PARAMS)  # traced: zero action
    assert float(current_objects(masked).x[0]) == pytest.approx(float(state.sdc.x[10]))


def test_stepping_past_the_end_stays_at_the_last_step(state):
    end = state.replace(timestep=jnp.int32(NUM_STEPS - 1))
    assert int(_step(end, jnp.zeros(3), PARAMS).timestep) == NUM_STEPS - 1


def test_bad_scenarios_raise_a_clear_error_before_tracing():
    sc = straight_road(scenario_id="bad-one")
    sc.metadata.is_sdc[:] = False
    with pytest.raises(DataError, match=r"'bad-one'.*exactly one SDC \(is_sdc\), found 0"):
        reset(sc, PARAMS)
    sc = straight_road()
    sc.trajectory.valid[0, CURRENT_INDEX] = False
    with pytest.raises(DataError, match="invalid at the current step"):
        reset(sc, PARAMS)
    with pytest.raises(ConfigError, match="offroad_method"):
        SimParams(offroad_method="nearest")
    with pytest.raises(ConfigError, match="edge_capacity"):
        SimParams(edge_capacity=0)


def test_reset_keeps_the_whole_roadgraph_and_every_road_edge():
    sc = straight_road()  # SDC at (0, 0) at step 10; edges y = +-5, x in -30..169 (1 m apart)
    rg = sc.roadgraph
    state = reset(sc, PARAMS)
    np.testing.assert_array_equal(np.asarray(state.roadgraph.valid), np.asarray(rg.valid))
    edges = state.road_edges
    ev = np.asarray(edges.valid)
    assert ev.sum() == 400  # every road-edge point of the map, wherever the log goes
    # segments run to the next point of the same polyline (a polyline's end: the point itself)
    d = np.abs(np.asarray(edges.next_xy)[ev] - np.asarray(edges.xy)[ev]).sum(-1)
    assert np.sum(np.abs(d - 1.0) < 1e-5) == 398 and np.sum(d == 0.0) == 2
    # over capacity: the nearest to the SDC's current position (step 10), not to its log
    select = jax.jit(select_road_edges, static_argnames="edge_capacity")
    few = select(rg, np.array([100.0, 0.0], np.float32), edge_capacity=100)
    x = np.asarray(few.xy)[np.asarray(few.valid), 0]
    assert len(x) <= 100 and np.abs(x - 100.0).max() <= 25.0 and len(x) >= 96
    assert set(np.unique(np.asarray(rg.type)[np.isin(rg.type, RG_ROAD_EDGE_TYPES)])) <= {15, 16}


def test_scenario_id_survives_reset(state):
    np.testing.assert_array_equal(state.scenario_id, encode_scenario_id("toy-straight"))
