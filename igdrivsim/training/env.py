"""The simulator as BC-RL's training sees it: the policy-driven closed-loop rollout.

Everything is time-major (``[T, B, ...]``) over a batch ``B`` of :class:`SimState` s taken at
reset (timestep 10). The episode is Waymax's: steps 0..9 are the logged warm-up (observed only,
to warm the GRU; the update does that from the teacher-forced observations), then 80
controlled steps 10..89. Each scenario of a batch has its own episode key (Gaussian noise
offset, masking draws); the observation's step key is ``fold_in(episode_key, t)``.

The rollout is the simulator's one runner
(:func:`igdrivsim.simulator.rollout.run_episode`) with the learned actor
(:func:`igdrivsim.policy.act.policy_actor`) acting on the whole batch; the reward is the
simulator's (``-1[overlap] - 1[offroad]``), zero where the logged SDC has no next pose.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS
from igdrivsim.observation import Observation
from igdrivsim.policy.act import PolicyCarry, observe_now, policy_actor
from igdrivsim.policy.network import PolicyConfig
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.simulator.rollout import Actor, run_episode

WARMUP_STEPS = CURRENT_INDEX  # observations at t = 0..9 warm the GRU
CONTROLLED_STEPS = NUM_STEPS - 1 - CURRENT_INDEX  # 80


class PolicyRollout(NamedTuple):
    obs: Observation  # [80, B, ...]
    actions: jax.Array  # int32 [80, B, 3], sampled bin indices
    log_probs: jax.Array  # [80, B]
    values: jax.Array  # [80, B]
    rewards: jax.Array  # [80, B], reward of the state reached by the action
    valid: jax.Array  # bool [80, B]
    privileged_obs: Observation | None = None  # [80, B, ...] the same states, fully observed


def policy_rollout(config: PolicyConfig, params, carry, state: SimState, setting, obs_config,
                   sim_params: SimParams, episode_keys, key,
                   num_steps: int = CONTROLLED_STEPS, privileged=None) -> PolicyRollout:
    """Drive a batch ``[B]`` with actions sampled from the policy, starting from the warmed-up
    GRU state ``carry [B, H]``; one draw per step for the whole batch from
    ``split(key, num_steps)``. ``privileged``: a setting (the teacher's, e.g. ``full``) under
    which every visited state is observed as well, for a teacher to label it."""
    actor = student = policy_actor(config, params, setting, obs_config, "sample")
    if privileged is not None:
        def step(s, pc, k):
            action, pc, info = student.step(s, pc, k)
            seen = observe_now(s, privileged, pc.episode_key, obs_config)
            return action, pc, info._replace(extras=(info.extras, seen))

        actor = Actor(step=step, init=student.init)
    _, tr = run_episode(state, actor, key, sim_params, carry=PolicyCarry(carry, episode_keys),
                        metrics_fn=None, observation=True, value=True, log_prob=True,
                        with_reward=True, num_steps=num_steps)
    levels, seen = tr.extras if privileged is not None else (tr.extras, None)
    rewards = jnp.where(tr.valid, tr.reward, 0.0)
    return PolicyRollout(tr.observation, levels, tr.log_prob, tr.value, rewards, tr.valid, seen)
