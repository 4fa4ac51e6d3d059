"""The shared core: the episode runner and GAE on hand-made environments, and that the maze and
the driving benchmark train through the same runner and loss terms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.core import episode, losses
from igdrivsim.core.episode import Actor, StepInfo, run_episode


def test_run_episode_threads_state_carry_and_keys():
    """A counter environment and an actor that counts its steps and reports its key."""

    def env_step(state, action):
        return state + action, state * 10

    def step(state, carry, key):
        return jnp.int32(2), carry + 1, StepInfo(observation=state, extras=key)

    key = jax.random.PRNGKey(7)
    final, carry, steps = run_episode(env_step, Actor(step=step, init=lambda s, k: 100),
                                      jnp.int32(1), key, 4)
    assert int(final) == 9 and int(carry) == 104
    np.testing.assert_array_equal(steps.info.observation, [1, 3, 5, 7])  # before each step
    np.testing.assert_array_equal(steps.out, [10, 30, 50, 70])
    np.testing.assert_array_equal(steps.info.extras, jax.random.split(key, 4))
    _, _, kept = run_episode(env_step, Actor(step=step), jnp.int32(1), key, 4, carry=0,
                             record=lambda s: s.out)
    np.testing.assert_array_equal(kept, [10, 30, 50, 70])


def _gae_by_loop(values, rewards, dones, last_value, gamma, lam):
    adv = np.zeros_like(values)
    next_adv, next_value = 0.0, last_value
    for t in reversed(range(len(values))):
        keep = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * keep - values[t]
        next_adv = delta + gamma * lam * keep * next_adv
        adv[t], next_value = next_adv, values[t]
    return adv


def test_gae_cuts_at_episode_ends():
    rng = np.random.default_rng(0)
    values, rewards = rng.normal(size=12).astype(np.float32), rng.normal(size=12).astype(
        np.float32)
    dones = np.zeros(12, np.float32)
    dones[[3, 8]] = 1.0
    adv, ret = losses.gae(jnp.asarray(values), jnp.asarray(rewards), jnp.asarray(dones, bool),
                          jnp.float32(0.7), 0.9, 0.8)
    np.testing.assert_allclose(adv, _gae_by_loop(values, rewards, dones, 0.7, 0.9, 0.8),
                               rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ret, np.asarray(adv) + values, rtol=1e-6)
    # The step that ends an episode neither bootstraps nor inherits the next episode's advantage.
    assert float(adv[3]) == np.float32(rewards[3] - values[3])


def test_categorical_terms_by_hand():
    logits = jnp.log(jnp.array([[0.5, 0.25, 0.25], [0.1, 0.1, 0.8]]))
    np.testing.assert_allclose(losses.log_prob(logits, jnp.array([1, 2])),
                               np.log([0.25, 0.8]), rtol=1e-6)
    np.testing.assert_allclose(losses.entropy(logits)[0], -(0.5 * np.log(0.5) + 0.5 * np.log(
        0.25)), rtol=1e-6)
    target = jax.nn.log_softmax(logits[::-1])
    np.testing.assert_allclose(losses.kl_divergence(target, logits),
                               losses.soft_cross_entropy(target, logits) - losses.entropy(
                                   logits[::-1]), rtol=1e-5, atol=1e-6)
    # clipped value loss: a value moved past the clip range is held at it when that is worse
    v = losses.clipped_value_loss(jnp.array([2.0]), jnp.array([0.0]), jnp.array([0.0]), 0.5)
    assert float(v) == 0.5 * 4.0


def test_maze_and_driving_share_the_runner_and_the_loss_terms():
    import importlib

    from igdrivsim.training import losses as driving_losses
    from maze import mixed, ppo, rollout

    driving = importlib.import_module("igdrivsim.simulator.rollout")
    assert rollout.run_episode is driving.episode.run_episode is episode.run_episode
    assert rollout.Actor is driving.Actor is episode.Actor
    for name in ("gae", "surrogate_terms", "normalize", "masked_mean"):
        assert getattr(driving_losses, name) is getattr(losses, name)
    assert ppo.gae is mixed.gae is losses.gae
    assert ppo.surrogate_terms is losses.surrogate_terms
