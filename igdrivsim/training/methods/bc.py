"""Behaviour cloning: the negative log-likelihood of the discretised expert actions on the
logged episodes (the paper's BC; ``w_BC BC + w_RL PPO`` with ``w_RL = 0``)."""

from __future__ import annotations

from igdrivsim.core.learn import masked_mean
from igdrivsim.names import LEARNED
from igdrivsim.policy.act import bc_loss, entropy
from igdrivsim.training.methods import Method, register_method


def logged_bc(spec, out, batch):
    """``(BC loss, metrics)`` on the logged episodes: shared by the methods that keep BC."""
    logits, valid = out["logged"].logits, batch["expert_valid"]
    bc = bc_loss(logits, batch["expert_actions"], valid)
    return bc, {"bc_loss": bc, "entropy": masked_mean(entropy(logits), valid)}


def loss(spec, out, batch):
    bc, metrics = logged_bc(spec, out, batch)
    return spec.loss.w_bc * bc, metrics


register_method(Method("bc", *LEARNED["bc"], loss, episodes=("logged",), baseline=None))
