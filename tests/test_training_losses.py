"""BC / PPO loss terms on hand-made inputs, and the GRU reset of the policy network."""

from __future__ import annotations

import math
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.core.learn import entropy, gae, normalize, surrogate_terms, value_loss
from igdrivsim.observation import ObservationConfig
from igdrivsim.policy.act import action_log_prob, choose_levels, example_observation
from igdrivsim.policy.network import (
    POOLED_NETWORK,
    PolicyConfig,
    apply_step,
    init_params,
    init_params_per_seed,
)
from igdrivsim.simulator.dynamics import undiscretize
from igdrivsim.training.methods.bc import bc_loss
from igdrivsim.training.update import cosine_lr


def test_bc_loss_uniform_and_peaked():
    k = 257
    uniform = jnp.zeros((2, 5, 3, k))
    actions = jnp.zeros((2, 5, 3), jnp.int32)
    assert float(bc_loss(uniform, actions)) == pytest.approx(3 * math.log(k), rel=1e-5)
    peaked = jnp.full((1, 3, k), -1e9).at[0, :, 7].set(0.0)
    assert float(bc_loss(peaked, jnp.full((1, 3), 7))) == pytest.approx(0.0, abs=1e-5)
    # The mask drops the steps it marks: only the first (peaked, correct) step counts.
    logits = jnp.stack([peaked[0], uniform[0, 0]])
    mask = jnp.array([True, False])
    assert float(bc_loss(logits, jnp.full((2, 3), 7), mask)) == pytest.approx(0.0, abs=1e-5)


def test_action_log_prob_sums_three_dimensions():
    logits = jnp.log(jnp.array([[0.5, 0.5, 0.0 + 1e-30], [0.25, 0.25, 0.5], [1.0, 1e-30, 1e-30]]))
    lp = action_log_prob(logits, jnp.array([0, 2, 0]))
    assert float(lp) == pytest.approx(math.log(0.5) + math.log(0.5) + 0.0, abs=1e-5)
    joint = entropy(jnp.zeros((3, 4))).sum(-1)  # the three dimensions' entropies summed
    assert float(joint) == pytest.approx(3 * math.log(4), rel=1e-6)


def test_gae_by_hand():
    rewards = jnp.array([[1.0, 0.0, 2.0]])
    values = jnp.array([[0.5, 1.0, 1.5]])
    gamma, lam = 0.9, 0.8
    adv, ret = gae(values, rewards, jnp.zeros((1, 3), bool), jnp.array([0.0]), gamma, lam,
                   axis=-1)
    d2 = 2.0 + 0.0 - 1.5
    d1 = 0.0 + gamma * 1.5 - 1.0
    d0 = 1.0 + gamma * 1.0 - 0.5
    a2, a1 = d2, d1 + gamma * lam * d2
    a0 = d0 + gamma * lam * a1
    np.testing.assert_allclose(adv[0], [a0, a1, a2], rtol=1e-6)
    np.testing.assert_allclose(ret, adv + values, rtol=1e-6)


def test_surrogate_clips_and_value_loss_shapes():
    adv = jnp.array([1.0, -1.0])
    # Ratio 2 with positive advantage is clipped at 1.2; ratio 0.5 with negative at 0.8.
    logp_new = jnp.log(jnp.array([2.0, 0.5]))
    loss = surrogate_terms(logp_new, jnp.zeros(2), adv, 0.2).mean()
    assert float(loss) == pytest.approx(-(1.2 * 1.0 + 0.8 * -1.0) / 2, rel=1e-6)
    # Equal log-probs: ratio 1, the loss is -mean(A).
    assert float(surrogate_terms(jnp.zeros(2), jnp.zeros(2), adv, 0.2).mean()) == pytest.approx(
        0.0)
    assert float(value_loss(jnp.ones((4, 3)), jnp.zeros((4, 3)))) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        value_loss(jnp.ones((4, 3)), jnp.zeros((4, 3, 1)))
    x = normalize(jnp.array([1.0, 2.0, 3.0, 100.0]), jnp.array([True, True, True, False]))
    np.testing.assert_allclose(np.asarray(x[:3]).mean(), 0.0, atol=1e-6)


def test_cosine_schedule():
    assert cosine_lr(0, 100, 1e-3, 0.0) == pytest.approx(1e-3)
    assert cosine_lr(50, 100, 1e-3, 0.0) == pytest.approx(5e-4)
    assert cosine_lr(100, 100, 1e-3, 0.0) == pytest.approx(0.0, abs=1e-12)


TINY = PolicyConfig(**POOLED_NETWORK, object_hidden=(8,), point_hidden=(8,),
                    roadgraph_hidden=(8,),
                    trunk_hidden=(8,), gru_hidden=8, actor_hidden=(8,), value_hidden=(8,))


def test_gru_reset_zeroes_the_state():
    from igdrivsim.observation import ObservationConfig

    obs = example_observation(ObservationConfig(3, 5))
    obs = obs.replace(sdc_speed=jnp.ones((1,)), objects=jnp.ones((3, 6)),
                      objects_valid=jnp.ones((3,), bool))
    params = jax.tree.map(lambda x: x[0], init_params_per_seed(TINY, [jax.random.PRNGKey(0)], obs))
    step = jax.jit(apply_step, static_argnums=0)
    hot = jnp.full((8,), 0.7)
    zero = jnp.zeros((8,))
    c_reset, logits_reset, _ = step(TINY, params, hot, obs, jnp.array(True))
    c_zero, logits_zero, _ = step(TINY, params, zero, obs, jnp.array(False))
    c_keep, logits_keep, _ = step(TINY, params, hot, obs, jnp.array(False))
    np.testing.assert_allclose(c_reset, c_zero, atol=1e-6)
    np.testing.assert_allclose(logits_reset, logits_zero, atol=1e-6)
    assert not np.allclose(c_keep, c_zero)
    # greedy picks the arg-max level (a bounded continuous action); mean takes the expected
    # level (between the levels, inside their range).
    levels = choose_levels(logits_zero, jax.random.PRNGKey(1), "greedy")
    np.testing.assert_array_equal(levels, jnp.argmax(logits_zero, -1))
    action = undiscretize(levels)
    assert action.shape == (3,) and float(jnp.abs(action[:2]).max()) <= 6.0
    mean = choose_levels(logits_zero, jax.random.PRNGKey(1), "mean")
    probs = jax.nn.softmax(logits_zero, -1)
    np.testing.assert_allclose(mean, (probs * jnp.arange(probs.shape[-1])).sum(-1), rtol=1e-5)


def test_relative_dx_head_scores_offsets_from_constant_velocity():
    from igdrivsim.policy.network import relative_to_constant_velocity, unroll_sequence
    from igdrivsim.simulator.dynamics import discretize

    # offset index 128 (zero offset) peaked: the most likely level is constant velocity's
    offsets = jnp.zeros((3, 257)).at[:, 128].set(5.0).at[:, 129].set(4.0)
    speeds = jnp.array([0.0, 4.7, 12.3])  # m/s
    levels = relative_to_constant_velocity(offsets, speeds / 50.0)
    cv = discretize(jnp.stack([speeds * 0.1, 0 * speeds, 0 * speeds], -1))[:, 0]
    np.testing.assert_array_equal(jnp.argmax(levels, -1), cv)
    np.testing.assert_allclose(jnp.take_along_axis(levels, cv[:, None] + 1, -1)[:, 0], 4.0)
    # the same policy stepped and unrolled gives the same logits (the head reads the speed)
    cfg = replace(TINY, relative_dx=True, speed_input_scale=10.0)
    obs = example_observation(ObservationConfig(2, 4))
    params = init_params(cfg, jax.random.PRNGKey(0), obs)
    seq = jax.tree.map(lambda x: jnp.stack([x] * 3)[:, None], obs)  # [T=3, B=1, ...]
    seq = seq.replace(sdc_speed=jnp.array([0.1, 0.2, 0.3])[:, None, None])
    _, unrolled, _ = unroll_sequence(cfg, params, jnp.zeros((1, cfg.gru_hidden)), seq)
    carry = jnp.zeros((1, cfg.gru_hidden))
    for t in range(3):
        o = jax.tree.map(lambda x, t=t: x[t], seq)
        carry, logits, _ = apply_step(cfg, params, carry, o, jnp.array([t == 0]))
        np.testing.assert_allclose(logits, unrolled[t], atol=1e-5)


def test_speed_history_feeds_the_last_speed_changes_in_levels():
    from igdrivsim.policy.network import initial_carry, speed_changes, unroll_sequence

    level = 0.46875 / 50.0  # one dx level (12/256 m per 0.1 s) in the feature's units
    v = jnp.array([[5.0, 5.5, 4.0]]) / 50.0  # now, previous, the one before (m/s / 50)
    changes, past = speed_changes(v[:, :1], v[:, 1:])
    np.testing.assert_allclose(changes, [[-0.5 / 50 / level, 1.5 / 50 / level]], rtol=1e-5)
    np.testing.assert_allclose(past, v[:, :2])
    # stepping and unrolling agree, the carry holds the speeds, and a reset forgets them
    cfg = replace(TINY, relative_dx=True, speed_history=2)
    obs = example_observation(ObservationConfig(2, 4))
    params = init_params(cfg, jax.random.PRNGKey(0), obs)
    speeds = jnp.array([0.10, 0.11, 0.13, 0.12])
    seq = jax.tree.map(lambda x: jnp.stack([x] * 4)[:, None], obs)  # [T=4, B=1, ...]
    seq = seq.replace(sdc_speed=speeds[:, None, None])
    end, unrolled, _ = unroll_sequence(cfg, params, initial_carry(cfg, (1,)), seq)
    carry = jnp.full((1, cfg.gru_hidden + 2), 0.5)  # a stale carry: the reset must drop it
    for t in range(4):
        o = jax.tree.map(lambda x, t=t: x[t], seq)
        carry, logits, _ = apply_step(cfg, params, carry, o, jnp.array([t == 0]))
        np.testing.assert_allclose(logits, unrolled[t], atol=1e-5)
    np.testing.assert_allclose(carry, end, atol=1e-5)
    np.testing.assert_allclose(end[0, -2:], [0.12, 0.13], atol=1e-7)
    # the changes reach the network: other past speeds, other logits
    other = seq.replace(sdc_speed=jnp.array([0.10, 0.10, 0.10, 0.12])[:, None, None])
    _, moved, _ = unroll_sequence(cfg, params, initial_carry(cfg, (1,)), other)
    assert not np.allclose(moved[3], unrolled[3])


def test_yaw_history_feeds_the_last_yaw_rates_in_levels_next_to_the_speed_history():
    from igdrivsim.policy.network import initial_carry, unroll_sequence, yaw_rate_levels

    level = 2 * np.pi / 256 / 0.1  # one dyaw level per 0.1 s, in rad/s
    levels, past = yaw_rate_levels(jnp.array([[2 * level]]), jnp.array([[-level, 0.5]]))
    np.testing.assert_allclose(levels, [[2.0, -1.0, 0.5 / level]], rtol=1e-5)
    np.testing.assert_allclose(past, [[2 * level, -level]], rtol=1e-6)
    cfg = replace(TINY, relative_dx=True, speed_history=2, yaw_history=3)
    obs = example_observation(ObservationConfig(2, 4))
    params = init_params(cfg, jax.random.PRNGKey(0), obs)
    seq = jax.tree.map(lambda x: jnp.stack([x] * 4)[:, None], obs)  # [T=4, B=1, ...]
    seq = seq.replace(sdc_speed=jnp.array([0.10, 0.11, 0.13, 0.12])[:, None, None],
                      sdc_yaw_rate=jnp.array([0.0, 0.2, -0.1, 0.3])[:, None, None])
    end, unrolled, _ = unroll_sequence(cfg, params, initial_carry(cfg, (1,)), seq)
    assert end.shape == (1, cfg.gru_hidden + 2 + 2)
    carry = jnp.full(end.shape, 0.5)  # a stale carry: the reset must drop it
    for t in range(4):
        o = jax.tree.map(lambda x, t=t: x[t], seq)
        carry, logits, _ = apply_step(cfg, params, carry, o, jnp.array([t == 0]))
        np.testing.assert_allclose(logits, unrolled[t], atol=1e-5)
    np.testing.assert_allclose(carry, end, atol=1e-5)
    np.testing.assert_allclose(end[0, -4:], [0.12, 0.13, 0.3, -0.1], atol=1e-7)
    # the yaw rates reach the network: another past turn, other logits
    other = seq.replace(sdc_yaw_rate=jnp.array([0.0, 0.0, 0.0, 0.3])[:, None, None])
    _, moved, _ = unroll_sequence(cfg, params, initial_carry(cfg, (1,)), other)
    assert not np.allclose(moved[3], unrolled[3])


def test_object_ego_speed_lets_the_object_encoder_read_the_ego_speed():
    from igdrivsim.observation import OBJECT_FEATURES
    from igdrivsim.policy.network import DrivingPolicy, initial_carry, unroll_sequence

    cfg = replace(TINY, object_ego_speed=True, speed_input_scale=10.0)
    obs = example_observation(ObservationConfig(2, 4))
    obs = obs.replace(objects=obs.objects.at[0].set(jnp.array([0.1, 0.0, 1.0, 0.0, 0.2, 1.0])),
                      objects_valid=obs.objects_valid.at[0].set(True))

    def per_object(c, o):  # the object MLP's output for each slot, and the parameters
        p = init_params(c, jax.random.PRNGKey(0), obs)
        _, state = DrivingPolicy(c).apply(p, o, None, method=DrivingPolicy.encode,
                                          capture_intermediates=True)
        return state["intermediates"]["object_mlp"]["__call__"][0], p

    slow, fast = obs.replace(sdc_speed=jnp.array([0.1])), obs.replace(sdc_speed=jnp.array([0.3]))
    out, params = per_object(cfg, slow)
    dense = params["params"]["object_mlp"]["Dense_0"]
    assert dense["kernel"].shape[0] == OBJECT_FEATURES + 1
    # the input is [the observed features with the object's speed x10, the ego speed x10]
    x = jnp.concatenate([obs.objects.at[:, 4].multiply(10.0), jnp.full((2, 1), 1.0)], -1)
    np.testing.assert_allclose(out, jax.nn.relu(x @ dense["kernel"] + dense["bias"]), atol=1e-6)
    assert not np.allclose(out, per_object(cfg, fast)[0])
    base = replace(cfg, object_ego_speed=False)  # off: the objects do not see the ego speed
    np.testing.assert_allclose(per_object(base, slow)[0], per_object(base, fast)[0])
    # stepping and unrolling agree
    seq = jax.tree.map(lambda v: jnp.stack([v] * 3)[:, None], obs)
    seq = seq.replace(sdc_speed=jnp.array([0.1, 0.2, 0.3])[:, None, None])
    _, unrolled, _ = unroll_sequence(cfg, params, initial_carry(cfg, (1,)), seq)
    carry = initial_carry(cfg, (1,))
    for t in range(3):
        o = jax.tree.map(lambda v, t=t: v[t], seq)
        carry, logits, _ = apply_step(cfg, params, carry, o, jnp.array([t == 0]))
        np.testing.assert_allclose(logits, unrolled[t], atol=1e-5)
