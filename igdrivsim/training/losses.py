"""BC and PPO loss terms on explicit arrays (no environment, no network): easy to test by hand.

Shapes: ``logits [..., 3, bins]`` and actions ``[..., 3]`` (dx, dy, dyaw bin indices); the log
probability of an action is the sum over the three independent categoricals. Sequences are
``[..., T]`` with time last.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from igdrivsim.policy.distribution import action_log_prob  # re-exported: the loss terms' base


def entropy(logits: jax.Array) -> jax.Array:
    """Entropy of the joint (product) distribution, ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(logp) * logp).sum(-1).sum(-1)


def masked_mean(x: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    if mask is None:
        return x.mean()
    mask = jnp.broadcast_to(mask, x.shape).astype(x.dtype)
    return (x * mask).sum() / jnp.maximum(mask.sum(), 1.0)


def bc_loss(logits: jax.Array, expert_actions: jax.Array, mask: jax.Array | None = None):
    """Mean negative log-likelihood of the discretised expert actions."""
    return masked_mean(-action_log_prob(logits, expert_actions), mask)


def gae(rewards: jax.Array, values: jax.Array, last_value: jax.Array, gamma: float,
        lam: float) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over the last axis (fixed-length episodes).

    ``rewards[..., t]`` follows the action at t; ``values[..., t]`` = V(s_t); ``last_value`` =
    V(s_T) (0 for a terminal state). Returns ``(advantages, returns)`` shaped like rewards.
    """
    next_values = jnp.concatenate([values[..., 1:], last_value[..., None]], axis=-1)
    deltas = rewards + gamma * next_values - values

    def body(acc, delta):
        acc = delta + gamma * lam * acc
        return acc, acc

    time_major = jnp.moveaxis(deltas, -1, 0)
    _, adv = jax.lax.scan(body, jnp.zeros_like(time_major[0]), time_major, reverse=True)
    adv = jnp.moveaxis(adv, 0, -1)
    return adv, adv + values


def surrogate_terms(logp_new: jax.Array, logp_old: jax.Array, advantages: jax.Array,
                    clip: float) -> jax.Array:
    """Per-state PPO policy loss ``-min(r A, clip(r, 1-eps, 1+eps) A)``, ``[...]``."""
    ratio = jnp.exp(logp_new - logp_old)
    return -jnp.minimum(ratio * advantages, jnp.clip(ratio, 1.0 - clip, 1.0 + clip) * advantages)


def clipped_surrogate(logp_new: jax.Array, logp_old: jax.Array, advantages: jax.Array,
                      clip: float, mask: jax.Array | None = None) -> jax.Array:
    """PPO policy loss (to minimise): -mean(min(r A, clip(r, 1-eps, 1+eps) A))."""
    return masked_mean(surrogate_terms(logp_new, logp_old, advantages, clip), mask)


def soft_cross_entropy(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """Cross-entropy of the policy ``logits [..., 3, bins]`` to a target distribution given by
    its log-probabilities (a teacher's), summed over the 3 dimensions: ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(target_logp) * logp).sum(-1).sum(-1)


def kl_divergence(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """KL(target || policy) summed over the 3 dimensions, ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return (jnp.exp(target_logp) * (target_logp - logp)).sum(-1).sum(-1)


def value_loss(values: jax.Array, returns: jax.Array, mask: jax.Array | None = None):
    """0.5 * mean squared error; both arguments must have the same shape (no broadcasting)."""
    if values.shape != returns.shape:
        raise ValueError(f"value_loss: values {values.shape} vs returns {returns.shape}")
    return 0.5 * masked_mean((values - returns) ** 2, mask)


def normalize(x: jax.Array, mask: jax.Array | None = None, eps: float = 1e-8) -> jax.Array:
    """Zero-mean unit-std advantages (statistics over the masked entries)."""
    mean = masked_mean(x, mask)
    std = jnp.sqrt(masked_mean((x - mean) ** 2, mask))
    return (x - mean) / (std + eps)
