"""The simulator as training sees it: warm-up observations, expert- and policy-driven rollouts.

Everything is time-major (``[T, B, ...]``) over a batch ``B`` of :class:`SimState` s taken at
reset (timestep 10). The episode is Waymax's: steps 0..9 are the logged warm-up (observed only,
to warm the GRU), then 80 controlled steps 10..89. Each scenario of a batch has its own episode
key (Gaussian noise offset, masking draws); the step key is ``fold_in(episode_key, t)``.

Expert actions, metrics and the reward are the simulator's (``igdrivsim.simulator.{expert,
metrics}``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS
from igdrivsim.observation import Observation, ObservationConfig, ObservationSetting, observe
from igdrivsim.policy.network import PolicyConfig, apply_step, initial_carry
from igdrivsim.simulator import SimParams, SimState, dynamics, step
from igdrivsim.simulator.expert import expert_action
from igdrivsim.simulator.metrics import reward, step_metrics
from igdrivsim.simulator.state import log_sdc_at
from igdrivsim.training.losses import action_log_prob

WARMUP_STEPS = CURRENT_INDEX  # observations at t = 0..9 warm the GRU
CONTROLLED_STEPS = NUM_STEPS - 1 - CURRENT_INDEX  # 80


def step_reward(state: SimState, params: SimParams) -> jax.Array:
    """Per-step reward of the state just reached: -1[overlap] - 1[offroad]."""
    return reward(step_metrics(state, params)).astype(jnp.float32)


def observe_batch(state: SimState, setting: ObservationSetting, obs_config: ObservationConfig,
                  episode_keys: jax.Array) -> Observation:
    """Observations of a batch of states ``[B]`` (one episode key per scenario)."""

    def one(s, k):
        return observe(s, setting, k, jax.random.fold_in(k, s.timestep), obs_config)

    return jax.vmap(one)(state, episode_keys)


def warmup_observations(state: SimState, setting, obs_config, episode_keys) -> Observation:
    """The logged warm-up ``t = 0..9`` as observations ``[10, B, ...]``."""

    def at(t):
        return observe_batch(state.replace(timestep=jnp.full_like(state.timestep, t)), setting,
                             obs_config, episode_keys)

    return jax.vmap(at)(jnp.arange(WARMUP_STEPS))


def sdc_step_valid(state: SimState) -> jax.Array:
    """Whether the logged SDC is valid now and at the next step (an action is defined)."""
    t = state.timestep
    return log_sdc_at(state, t)[3] & log_sdc_at(state, jnp.minimum(t + 1, NUM_STEPS - 1))[3]


class ExpertRollout(NamedTuple):
    obs: Observation  # [80, B, ...]
    actions: jax.Array  # int32 [80, B, 3], discretised expert actions
    valid: jax.Array  # bool [80, B]


def expert_rollout(state: SimState, setting, obs_config, sim_params: SimParams,
                   episode_keys, num_steps: int = CONTROLLED_STEPS) -> ExpertRollout:
    """Drive with the discretised expert (inverse to the next logged pose from the *simulated*
    pose, so quantisation error is corrected); record observations and expert actions."""

    def body(s, _):
        obs = observe_batch(s, setting, obs_config, episode_keys)
        idx = dynamics.discretize(expert_action(s, sim_params))
        valid = sdc_step_valid(s)
        s = step(s, dynamics.undiscretize(idx), sim_params)
        return s, (obs, idx, valid)

    _, (obs, actions, valid) = jax.lax.scan(body, state, None, length=num_steps)
    return ExpertRollout(obs, actions, valid)


class PolicyRollout(NamedTuple):
    obs: Observation  # [80, B, ...]
    actions: jax.Array  # int32 [80, B, 3], sampled bin indices
    log_probs: jax.Array  # [80, B]
    values: jax.Array  # [80, B]
    rewards: jax.Array  # [80, B], reward of the state reached by the action
    valid: jax.Array  # bool [80, B]


def scan_policy(config: PolicyConfig, params, carry, obs_seq: Observation, reset_first: bool):
    """Run the network over time-major observations: ``(carry, logits [T,B,3,K], values [T,B])``.

    ``reset_first`` zeroes the GRU state before the first step (an episode start)."""
    t = jax.tree.leaves(obs_seq)[0].shape[0]
    b = carry.shape[:-1]
    resets = jnp.zeros((t, *b), bool).at[0].set(reset_first)

    def body(c, xs):
        obs, reset = xs
        c, logits, value = apply_step(config, params, c, obs, reset)
        return c, (logits, value)

    if config.remat:
        body = jax.checkpoint(body)
    carry, (logits, values) = jax.lax.scan(body, carry, (obs_seq, resets))
    return carry, logits, values


def warm_carry(config: PolicyConfig, params, warm_obs: Observation) -> jax.Array:
    """GRU state after the warm-up observations ``[10, B, ...]`` (state reset at t = 0)."""
    b = jax.tree.leaves(warm_obs)[0].shape[1]
    carry, _, _ = scan_policy(config, params, initial_carry(config, (b,)), warm_obs, True)
    return carry


def policy_rollout(config: PolicyConfig, params, carry, state: SimState, setting, obs_config,
                   sim_params: SimParams, episode_keys, key,
                   num_steps: int = CONTROLLED_STEPS) -> PolicyRollout:
    """Drive with actions sampled from the policy, starting from the warmed-up ``carry``."""

    def body(c, k):
        s, h = c
        obs = observe_batch(s, setting, obs_config, episode_keys)
        h, logits, value = apply_step(config, params, h, obs, jnp.zeros(h.shape[:-1], bool))
        idx = jax.random.categorical(k, logits).astype(jnp.int32)
        valid = sdc_step_valid(s)
        s = step(s, dynamics.undiscretize(idx), sim_params)
        r = jnp.where(valid, step_reward(s, sim_params), 0.0)
        return (s, h), (obs, idx, action_log_prob(logits, idx), value, r, valid)

    _, out = jax.lax.scan(body, (state, carry), jax.random.split(key, num_steps))
    return PolicyRollout(*out)
