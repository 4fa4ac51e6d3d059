"""The minigrid/gymnasium maze and the pure-JAX maze produce identical episodes."""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from maze import env as E
from maze.gym_env import ENV_ID

P = E.make_params()
AUTO_STEP = jax.jit(E.auto_step, static_argnums=2)
OBS = jax.jit(E.observe, static_argnums=(1, 2))


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("kind", ["partial", "full"])
def test_gym_and_jax_agree(seed, kind):
    env = gym.make(ENV_ID, obs_kind=kind).unwrapped
    obs, info = env.reset(seed=seed)
    state = E.reset(jax.random.PRNGKey(seed), P)
    actions = np.random.default_rng(seed).integers(0, 4, size=600)
    episodes = 0
    for action in actions:
        assert info["position"] == tuple(np.asarray(state.pos))
        assert info["goal"] == tuple(np.asarray(state.goal))
        np.testing.assert_array_equal(obs, np.asarray(OBS(state, P, kind)))
        obs, reward, terminated, truncated, info = env.step(action)
        state, j_reward, j_done = AUTO_STEP(state, jnp.int32(action), P)
        assert reward == pytest.approx(float(j_reward), abs=1e-5)
        assert (terminated or truncated) == bool(j_done)
        if terminated or truncated:
            episodes += 1
            obs, info = env.reset()  # continues the key chain, like the JAX auto-reset
    assert episodes >= 2


def test_reaching_the_goal_terminates_with_the_paper_reward():
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=1)
    env.goal = (7, 8)
    _, reward, terminated, truncated, _ = env.step(3)
    assert terminated and not truncated and reward == pytest.approx(10 - 9 / 200)


def test_render_highlights_the_centred_view():
    env = gym.make(ENV_ID, render_mode="rgb_array", tile_size=8).unwrapped
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (15 * 8, 15 * 8, 3) and frame.dtype == np.uint8
    plain = env.get_full_render(False, 8)
    changed = np.argwhere((frame != plain).any(axis=2))
    rows, cols = changed[:, 0] // 8, changed[:, 1] // 8
    assert set(rows.tolist()) == {6, 7, 8} and set(cols.tolist()) == {6, 7, 8}
