"""BC-RL, the paper's remedy: ``w_BC BC + w_RL PPO``, BC on the logged episodes and PPO
(clipped surrogate + ``vf_coef`` value loss - ``ent_coef`` entropy) on the policy's own
closed-loop episode of the same scenarios."""

from __future__ import annotations

import jax.numpy as jnp

from igdrivsim.core.learn import entropy, log_prob, masked_mean, surrogate_terms, value_loss
from igdrivsim.names import LEARNED
from igdrivsim.training.methods import Method, register_method
from igdrivsim.training.methods.bc import logged_bc


def ppo(spec, rollout, batch):
    """``(PPO loss, metrics)`` of the rollout outputs against the collected batch."""
    mask = batch["valid"]
    logp = log_prob(rollout.logits, batch["actions"]).sum(-1)
    pg = masked_mean(surrogate_terms(logp, batch["log_probs"], batch["advantages"],
                                     spec.loss.clip_eps), mask)
    vl = value_loss(rollout.values, batch["returns"], mask)
    ent = masked_mean(entropy(rollout.logits).sum(-1), mask)
    ratio = jnp.exp(logp - batch["log_probs"])
    return pg + spec.loss.vf_coef * vl - spec.loss.ent_coef * ent, {
        "policy_loss": pg, "value_loss": vl, "policy_entropy": ent,
        "clip_frac": masked_mean((jnp.abs(ratio - 1) > spec.loss.clip_eps).astype(jnp.float32),
                                 mask),
        "ratio_dev": masked_mean(jnp.abs(ratio - 1.0), mask)}


def loss(spec, out, batch):
    bc, metrics = logged_bc(spec, out, batch)
    rl, rl_metrics = ppo(spec, out["rollout"], batch)
    return spec.loss.w_bc * bc + spec.loss.w_rl * rl, metrics | rl_metrics | {"ppo_loss": rl}


register_method(Method("bc_rl", *LEARNED["bc_rl"], loss, episodes=("logged", "rollout")))
