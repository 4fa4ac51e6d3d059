"""The policy acting: its action distribution, the actor, and its own training episodes.

The action distribution is three independent categoricals (dx, dy, dyaw levels): logits
``[..., 3, bins]`` and actions ``[..., 3]`` (level indices). An episode (training and
evaluation alike) observes the logged warm-up steps ``t = 0..9`` (GRU state zeroed at ``t =
0``), then at every controlled step ``t = 10..89`` observes, steps the GRU and picks one of
257 levels per dimension by the action mode (:data:`ACTION_MODES`: ``sample``, the paper's;
``greedy``; ``mean``, the expected level, a diagnostic). Every closed-loop episode of a
learned policy runs :func:`policy_actor` through the simulator's ``run_episode``;
:func:`policy_rollout` is BC-RL's training rollout.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.core.learn import log_prob
from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS
from igdrivsim.observation import ROADGRAPH_FEATURES, Observation, ObservationConfig, observe
from igdrivsim.observation.features import DEFAULT_CONFIG
from igdrivsim.policy.network import PolicyConfig, apply_step, initial_carry
from igdrivsim.simulator.dynamics import undiscretize
from igdrivsim.simulator.rollout import Actor, StepInfo, run_episode
from igdrivsim.simulator.state import SimParams, SimState, vmap_batch


def action_log_prob(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """log pi(a), summed over the 3 dimensions: ``[...]``."""
    return log_prob(logits, actions).sum(-1)


def example_observation(obs_config: ObservationConfig = DEFAULT_CONFIG) -> Observation:
    """An all-zero unbatched observation (shapes for parameter initialisation)."""
    n, m = obs_config.num_objects, obs_config.num_roadgraph_points
    return Observation(objects=jnp.zeros((n, 6)), objects_valid=jnp.zeros((n,), bool),
                       roadgraph=jnp.zeros((m, ROADGRAPH_FEATURES)),
                       roadgraph_valid=jnp.zeros((m,), bool), sdc_speed=jnp.zeros((1,)),
                       sdc_yaw_rate=jnp.zeros((1,)))


ACTION_MODES = ("sample", "greedy", "mean")


def choose_levels(logits: jax.Array, key: jax.Array, mode: str = "sample") -> jax.Array:
    """Levels ``[..., 3]`` from logits ``[..., 3, 257]`` by action mode (``mean``: the expected
    level, fractional; the others: int32)."""
    if mode == "sample":
        return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)
    if mode == "greedy":
        return jnp.argmax(logits, axis=-1).astype(jnp.int32)
    if mode == "mean":
        probs = jax.nn.softmax(logits, axis=-1)
        return jnp.sum(probs * jnp.arange(logits.shape[-1], dtype=probs.dtype), axis=-1)
    raise ValueError(f"action mode must be one of {ACTION_MODES}, got {mode!r}")


def warmup_carry(config: PolicyConfig, params, state, setting, obs_config: ObservationConfig,
                 episode_key: jax.Array) -> jax.Array:
    """GRU state after observing the logged steps ``0..9`` of ONE scenario (``state`` at reset,
    timestep 10), exactly as in training."""

    def body(carry, t):
        s = state.replace(timestep=jnp.asarray(t, state.timestep.dtype))
        obs = observe(s, setting, episode_key, jax.random.fold_in(episode_key, t), obs_config)
        carry, _, _ = apply_step(config, params, carry, obs, t == 0)
        return carry, None

    carry, _ = jax.lax.scan(body, initial_carry(config), jnp.arange(CURRENT_INDEX))
    return carry


@struct.dataclass
class PolicyCarry:
    """The learned actor's carry: the GRU state, the episode key(s) (step ``t`` observes with
    ``fold_in(episode_key, t)``) and the action key (levels drawn with ``fold_in(action_key,
    t)``; ``None``: with the runner's step key, as BC-RL's training rollout)."""

    hidden: jax.Array  # f32[..., gru_hidden + H]: the network's carry (initial_carry)
    episode_key: jax.Array  # key[...]
    action_key: jax.Array | None = None  # key[...] or None


def observe_now(state, setting, episode_key: jax.Array, obs_config: ObservationConfig
                ) -> Observation:
    """The observation of ``state`` (one scenario or a batch with one episode key each), with
    the step key ``fold_in(episode_key, t)``."""

    def one(s, k):
        return observe(s, setting, k, jax.random.fold_in(k, s.timestep), obs_config)

    return vmap_batch(one, jnp.ndim(state.timestep))(state, episode_key)


def policy_actor(config: PolicyConfig, params, setting, obs_config: ObservationConfig,
                 mode: str = "sample") -> Actor:
    """The learned policy as an actor of :func:`igdrivsim.simulator.rollout.run_episode`.

    ``init(state, key)`` (one scenario at reset) splits ``key`` into the episode and action
    keys and warms the GRU (:func:`warmup_carry`); ``step`` reports a ``StepInfo`` with the
    observation, the value, the levels' log-probability (not in ``mean`` mode) and the levels
    as ``extras``. ``params`` and ``setting`` may be traced.
    """
    def init(state, key) -> PolicyCarry:
        episode_key, action_key = jax.random.split(key)
        hidden = warmup_carry(config, params, state, setting, obs_config, episode_key)
        return PolicyCarry(hidden, episode_key, action_key)

    def step(state, carry: PolicyCarry, key) -> tuple[jax.Array, PolicyCarry, Any]:
        obs = observe_now(state, setting, carry.episode_key, obs_config)
        h = carry.hidden
        h, logits, value = apply_step(config, params, h, obs, jnp.zeros(h.shape[:-1], bool))
        if carry.action_key is None:
            levels = choose_levels(logits, key, mode)
        else:
            def pick(lg, k, t):
                return choose_levels(lg, jax.random.fold_in(k, t), mode)

            levels = vmap_batch(pick, jnp.ndim(state.timestep))(
                logits, carry.action_key, state.timestep)
        log_prob = None if mode == "mean" else action_log_prob(logits, levels)
        info = StepInfo(observation=obs, value=value, log_prob=log_prob, extras=levels)
        return undiscretize(levels), carry.replace(hidden=h), info

    return Actor(step=step, init=init)


WARMUP_STEPS = CURRENT_INDEX  # observations at t = 0..9 warm the GRU
CONTROLLED_STEPS = NUM_STEPS - 1 - CURRENT_INDEX  # 80


class PolicyRollout(NamedTuple):
    obs: Observation  # [80, B, ...]
    actions: jax.Array  # int32 [80, B, 3], sampled bin indices
    log_probs: jax.Array  # [80, B]
    values: jax.Array  # [80, B]
    rewards: jax.Array  # [80, B], -1[overlap] - 1[offroad] of the state reached (0 without a
    # next logged pose)
    valid: jax.Array  # bool [80, B]
    privileged_obs: Observation | None = None  # [80, B, ...] the same states, fully observed


def policy_rollout(config: PolicyConfig, params, carry, state: SimState, setting, obs_config,
                   sim_params: SimParams, episode_keys, key, privileged=None) -> PolicyRollout:
    """Drive a batch ``[B]`` with sampled actions from the warmed-up GRU state ``carry [B,
    H]``; ``privileged``: a setting (the teacher's) under which every visited state is observed
    as well, for a teacher to label it."""
    actor = student = policy_actor(config, params, setting, obs_config, "sample")
    if privileged is not None:
        def step(s, pc, k):
            action, pc, info = student.step(s, pc, k)
            seen = observe_now(s, privileged, pc.episode_key, obs_config)
            return action, pc, info._replace(extras=(info.extras, seen))

        actor = Actor(step=step, init=student.init)
    _, tr = run_episode(state, actor, key, sim_params, carry=PolicyCarry(carry, episode_keys),
                        metrics_fn=None, observation=True, value=True, log_prob=True,
                        with_reward=True, num_steps=CONTROLLED_STEPS)
    levels, seen = tr.extras if privileged is not None else (tr.extras, None)
    rewards = jnp.where(tr.valid, tr.reward, 0.0)
    return PolicyRollout(tr.observation, levels, tr.log_prob, tr.value, rewards, tr.valid, seen)
