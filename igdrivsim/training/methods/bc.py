"""Behaviour cloning: the negative log-likelihood of the discretised expert actions on the
logged episodes (the paper's BC; ``w_BC BC + w_RL PPO`` with ``w_RL = 0``)."""

from __future__ import annotations

import jax

from igdrivsim.core.learn import entropy, log_prob, masked_mean
from igdrivsim.names import LEARNED
from igdrivsim.training.methods import Method, register_method

# The policy is three independent categoricals (dx, dy, dyaw levels): every method's term of the
# joint distribution is the core's per-categorical term summed over the three (``.sum(-1)``).


def bc_loss(logits: jax.Array, expert_actions: jax.Array, mask: jax.Array | None = None):
    """Mean negative log-likelihood of the discretised expert actions ``[..., 3]``."""
    return masked_mean(-log_prob(logits, expert_actions).sum(-1), mask)


def logged_bc(spec, out, batch):
    """``(BC loss, metrics)`` on the logged episodes: shared by the methods that keep BC."""
    logits, valid = out["logged"].logits, batch["expert_valid"]
    bc = bc_loss(logits, batch["expert_actions"], valid)
    return bc, {"bc_loss": bc, "entropy": masked_mean(entropy(logits).sum(-1), valid)}


def loss(spec, out, batch):
    bc, metrics = logged_bc(spec, out, batch)
    return spec.loss.w_bc * bc, metrics


register_method(Method("bc", *LEARNED["bc"], loss, episodes=("logged",), baseline=None))
