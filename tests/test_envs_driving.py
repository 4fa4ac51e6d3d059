"""The Gymnasium driving environment: the checker, a random policy, the discretised expert
(stays on the log), and the batched JAX functions."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import igdrivsim.envs  # noqa: F401  (registers IGDrivSim/Driving-v0)
from igdrivsim.data import stack_scenarios
from igdrivsim.envs import ENV_ID, DrivingEnv
from igdrivsim.errors import ConfigError

SAMPLE = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scenarionet"
          / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")


@pytest.fixture(scope="module")
def env():
    if not SAMPLE.exists():
        pytest.skip(f"ScenarioNet sample not found at {SAMPLE}")
    return gym.make(ENV_ID, data=str(SAMPLE), setting="circular_r4")


def _episode(env, policy, seed: int, index: int = 0):
    obs, info = env.reset(seed=seed, options={"index": index})
    assert env.observation_space.contains(obs) and info["timestep"] == 10
    rewards, steps = [], 0
    while True:
        obs, rew, terminated, truncated, info = env.step(policy())
        assert env.observation_space.contains(obs) and not terminated
        assert rew == -float(info["overlap"]) - float(info["offroad"])
        rewards.append(rew)
        steps += 1
        if truncated:
            return steps, rewards, info


def test_checker_passes(env):
    with pytest.warns(UserWarning):  # unbounded feature boxes: the checker only warns
        check_env(env.unwrapped, skip_render_check=True)


def test_random_policy_and_expert_episodes(env):
    env.action_space.seed(0)
    steps, rewards, info = _episode(env, env.action_space.sample, seed=1)
    assert steps == 80 and info["timestep"] == 90
    assert set(info) >= {"overlap_rate", "offroad_rate", "max_log_divergence", "scenario_id"}
    assert info["max_log_divergence"] > 1.0  # random deltas leave the log
    steps, rewards, info = _episode(env, env.unwrapped.expert_action, seed=2, index=1)
    assert steps == 80 and sum(rewards) == 0.0
    assert info["max_log_divergence"] < 0.1 and info["offroad_rate"] == 0.0
    with pytest.raises(ConfigError):
        env.unwrapped.step(np.array([0, 0, 999]))


def test_continuous_actions_and_scenario_objects(env):
    scenarios = env.unwrapped.scenarios
    cont = DrivingEnv(scenarios, setting="circular_r4", continuous=True)
    assert isinstance(cont.action_space, gym.spaces.Box) and cont.action_space.shape == (3,)
    cont.reset(seed=0)
    obs, rew, _, _, info = cont.step(np.zeros(3, np.float32))
    assert cont.observation_space.contains(obs) and info["timestep"] == 11


def test_batched_functions_match_the_single_env(env):
    fns = env.unwrapped.fns
    batch = stack_scenarios(env.unwrapped.scenarios)
    keys = np.stack([jax.random.PRNGKey(0)] * 2)
    state, obs = fns.batch_reset(batch, keys)
    assert obs.objects.shape[0] == 2
    for _ in range(3):
        action = fns.batch_expert(state)
        state, obs, rew, done, metrics = fns.batch_step(state, action)
    assert np.all(np.asarray(state.sim.timestep) == 13) and not np.any(done)
    assert np.all(np.asarray(metrics.log_divergence) < 0.1) and np.all(np.asarray(rew) == 0)
    one, _ = fns.reset(env.unwrapped.scenarios[1], jax.random.PRNGKey(0))
    for _ in range(3):
        one, obs1, *_ = fns.step(one, fns.expert(one))
    np.testing.assert_allclose(np.asarray(obs1.objects), np.asarray(obs.objects[1]), atol=1e-5)
