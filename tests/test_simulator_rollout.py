"""Expert actor and rollouts: log replay accuracy, batching (vmap and leading dims), real WOMD."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS, stack_scenarios
from igdrivsim.simulator import SimParams, reset
from igdrivsim.simulator.rollout import (
    constant_velocity_actor,
    expert_action,
    expert_actor,
    expert_discrete_action,
    log_metrics,
    rollout,
)
from igdrivsim.simulator.toy import set_object, straight_road

PARAMS = SimParams()
_reset = jax.jit(reset, static_argnums=1)


def curved_road(speed: float, turn_rate: float):
    """The toy road with the SDC driving an arc (``turn_rate`` rad/s) at ``speed``."""
    sc = straight_road(speed=speed)
    t = np.arange(NUM_STEPS) * 0.1
    yaw = turn_rate * t
    if turn_rate:
        x = -10.0 + speed / turn_rate * np.sin(yaw)
        y = speed / turn_rate * (1.0 - np.cos(yaw))
    else:
        x, y = -10.0 + speed * t, np.zeros_like(t)
    set_object(sc, 0, x, y, yaw, sdc=True)
    return sc


@pytest.fixture(scope="module")
def batch():
    """Three toy scenarios stacked (straight, gentle and sharper curve), reset."""
    scs = [curved_road(10.0, 0.0), curved_road(8.0, 0.1), curved_road(6.0, 0.3)]
    return _reset(stack_scenarios(scs), PARAMS)


_jit_rollout = jax.jit(rollout, static_argnums=(1, 3))


@functools.cache
def _vmapped(policy):
    return jax.jit(jax.vmap(lambda s, k: rollout(s, policy, k, PARAMS)))


@pytest.fixture(scope="module")
def expert_vmapped(batch):
    """The discretised expert on the batch, vmapped: ``(keys, final, metrics, actions)``."""
    keys = jax.random.split(jax.random.key(1), 3)
    return (keys, *_vmapped(expert_actor(PARAMS))(batch, keys))


def test_continuous_expert_replays_the_log_exactly(batch):
    curved = jax.tree.map(lambda a: a[2], batch)
    _, m, actions = _jit_rollout(curved, expert_actor(PARAMS, discrete=False), jax.random.key(0),
                                 PARAMS)
    assert m.log_divergence.shape == (80,) and actions.shape == (80, 3)
    assert float(jnp.max(m.log_divergence)) < 1e-3
    assert bool(jnp.all(m.valid))


def test_discretised_expert_stays_within_quantisation_error(batch, expert_vmapped):
    _, final, m, idx = expert_vmapped
    assert idx.dtype == jnp.int32 and idx.shape == (3, 80, 3)
    assert np.all(np.asarray(final.timestep) == NUM_STEPS - 1)
    # half a level is 12/256/2 = 0.023 m per axis; the expert corrects the error every step
    assert float(jnp.max(m.log_divergence)) < 0.05
    assert float(jnp.mean(m.log_divergence)) < 0.03
    # the replay overlaps / leaves the road exactly where the log does (the arcs leave it)
    log = jax.jit(log_metrics, static_argnums=1)(batch, PARAMS)
    np.testing.assert_array_equal(m.overlap, log.overlap)
    np.testing.assert_array_equal(m.offroad, log.offroad)
    np.testing.assert_array_equal(m.offroad.any(-1), [False, True, True])  # per scenario


def test_vmap_and_leading_batch_dims_agree_with_single_scenarios(batch, expert_vmapped):
    policy = expert_actor(PARAMS)
    keys, _, m_vmap, a_vmap = expert_vmapped
    _, m_lead, a_lead = _jit_rollout(batch, policy, keys[0], PARAMS)
    one = jax.tree.map(lambda a: a[1], batch)
    _, m_one, a_one = _jit_rollout(one, policy, keys[1], PARAMS)
    np.testing.assert_array_equal(a_vmap, a_lead)
    np.testing.assert_array_equal(a_vmap[1], a_one)
    np.testing.assert_allclose(m_vmap.log_divergence[1], m_one.log_divergence, atol=1e-6)
    np.testing.assert_allclose(m_lead.log_divergence, m_vmap.log_divergence, atol=1e-6)


def test_constant_velocity_actor_follows_a_constant_speed_log(batch):
    straight = jax.tree.map(lambda a: a[0], batch)
    _, m, _ = _jit_rollout(straight, constant_velocity_actor(PARAMS), jax.random.key(0), PARAMS)
    assert float(jnp.max(m.log_divergence)) < 1e-3
    curved = jax.tree.map(lambda a: a[2], batch)
    _, m, _ = _jit_rollout(curved, constant_velocity_actor(PARAMS), jax.random.key(0), PARAMS)
    assert float(jnp.max(m.log_divergence)) > 5.0  # it cannot follow the turn


def test_expert_zero_action_when_next_log_step_invalid(batch):
    st = jax.tree.map(lambda a: a[1], batch)
    st = st.replace(log=st.log.replace(valid=st.log.valid.at[0, CURRENT_INDEX + 1].set(False)))
    _, m, idx = _jit_rollout(st, expert_actor(PARAMS), jax.random.key(0), PARAMS)
    np.testing.assert_array_equal(idx[0], 128)  # level 128 is the zero action
    assert not bool(m.valid[0]) and bool(m.valid[1])
    assert float(m.log_divergence[0]) == 0.0
    # back on the log right after the gap (the jump is within the action bounds)
    assert float(jnp.max(m.log_divergence[1:])) < 0.05
    # the continuous expert function itself
    one = jax.tree.map(lambda a: a[1], batch)
    gap = jax.jit(expert_action, static_argnums=1)(
        one.replace(log=st.log), PARAMS)
    np.testing.assert_array_equal(gap, 0.0)
    assert float(jnp.abs(jax.jit(expert_discrete_action, static_argnums=1)(one, PARAMS)
                         - 128).max()) > 0


def test_policy_gets_a_fresh_key_and_its_carry_every_step(batch):
    def policy(state, carry, key):
        u = jax.random.uniform(key)
        return jnp.zeros(state.timestep.shape + (3,)), carry + 1, (u, carry)

    one = jax.tree.map(lambda a: a[0], batch)
    final, _, (u, counts) = rollout(one, policy, jax.random.key(3), PARAMS, carry=jnp.int32(0))
    assert len(np.unique(np.asarray(u))) == 80
    np.testing.assert_array_equal(counts, np.arange(80))
    assert int(final.timestep) == NUM_STEPS - 1
