"""The policy's action distribution, three independent categoricals (dx, dy, dyaw bins), and the
loss terms over it that the learning methods sum: the shared categorical terms of
:mod:`igdrivsim.core.learn` summed over the three action dimensions.

Shapes: ``logits [..., 3, bins]`` and actions ``[..., 3]`` (bin indices). It lives with the
policy (acting needs the log-probability) so that ``policy`` does not import ``training``. GAE,
the PPO terms and the masked statistics are the core's, re-exported here for the methods.
"""

from __future__ import annotations

import jax

from igdrivsim.core import learn as core
from igdrivsim.core.learn import gae, log_prob, masked_mean, normalize, surrogate_terms, value_loss

__all__ = ["action_log_prob", "bc_loss", "clipped_surrogate", "entropy", "gae", "kl_divergence",
           "masked_mean", "normalize", "soft_cross_entropy", "surrogate_terms", "value_loss"]


def action_log_prob(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """log pi(a) = sum over the 3 dimensions of log softmax(logits)[a_d]; ``[...]``."""
    return log_prob(logits, actions).sum(-1)


def entropy(logits: jax.Array) -> jax.Array:
    """Entropy of the joint (product) distribution, ``[...]``."""
    return core.entropy(logits).sum(-1)


def soft_cross_entropy(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """Cross-entropy of the policy to a target distribution (a teacher's log-probabilities),
    summed over the 3 dimensions: ``[...]``."""
    return core.soft_cross_entropy(target_logp, logits).sum(-1)


def kl_divergence(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """KL(target || policy) summed over the 3 dimensions, ``[...]``."""
    return core.kl_divergence(target_logp, logits).sum(-1)


def bc_loss(logits: jax.Array, expert_actions: jax.Array, mask: jax.Array | None = None):
    """Mean negative log-likelihood of the discretised expert actions."""
    return masked_mean(-action_log_prob(logits, expert_actions), mask)


def clipped_surrogate(logp_new: jax.Array, logp_old: jax.Array, advantages: jax.Array,
                      clip: float, mask: jax.Array | None = None) -> jax.Array:
    """PPO policy loss (to minimise): -mean(min(r A, clip(r, 1-eps, 1+eps) A))."""
    return masked_mean(surrogate_terms(logp_new, logp_old, advantages, clip), mask)
