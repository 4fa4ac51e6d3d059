"""Acting with a trained policy: the GRU warm-up on the logged steps and one action step.

The training episode (and therefore evaluation) is: observe the logged warm-up steps
``t = 0..9`` (GRU state zeroed at ``t = 0``), then at every controlled step ``t = 10..89``
observe, step the GRU, pick one of 257 levels per dimension and convert it to the continuous
delta-local action ``(dx, dy, dyaw)``. How the level is picked is the *action mode*
(:data:`ACTION_MODES`): ``sample`` (the paper's protocol), ``greedy`` (the most likely level)
or ``mean`` (the expected level, a continuous action between levels: the policy's average
intent without the sampling noise, a diagnostic).

For one scenario (``vmap`` for batches / seeds)::

    carry = warmup_carry(cfg, params, state, setting, obs_config, episode_key)  # state at reset
    obs = observe(state, setting, episode_key, fold_in(episode_key, state.timestep), obs_config)
    action, carry, levels = policy_step(cfg, params, carry, obs, key, mode="sample")
    state = step(state, action, sim_params)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from igdrivsim.data.scenario import CURRENT_INDEX
from igdrivsim.observation import ROADGRAPH_FEATURES, Observation, ObservationConfig, observe
from igdrivsim.observation.features import DEFAULT_CONFIG
from igdrivsim.policy.network import PolicyConfig, apply_step, initial_carry
from igdrivsim.simulator.dynamics import undiscretize


def example_observation(obs_config: ObservationConfig = DEFAULT_CONFIG) -> Observation:
    """An all-zero unbatched observation (shapes for parameter initialisation)."""
    n, m = obs_config.num_objects, obs_config.num_roadgraph_points
    return Observation(objects=jnp.zeros((n, 6)), objects_valid=jnp.zeros((n,), bool),
                       roadgraph=jnp.zeros((m, ROADGRAPH_FEATURES)),
                       roadgraph_valid=jnp.zeros((m,), bool), sdc_speed=jnp.zeros((1,)))


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


def policy_step(config: PolicyConfig, params, carry: jax.Array, obs: Observation,
                key: jax.Array, mode: str = "sample", reset=False):
    """One step: ``-> (action f32[..., 3] continuous delta-local, carry, levels [..., 3])``.

    ``reset`` zeroes the GRU state first (an episode start; the warm-up does this at t = 0).
    """
    reset = jnp.broadcast_to(jnp.asarray(reset, bool), carry.shape[:-1])
    carry, logits, _ = apply_step(config, params, carry, obs, reset)
    levels = choose_levels(logits, key, mode)
    return undiscretize(levels), carry, levels


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
