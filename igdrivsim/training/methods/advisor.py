"""Adaptive imitation weighting (ADVISOR, Weihs et al. 2021; the idea, our code).

The student drives its own closed-loop episodes; the privileged teacher (``training.teacher``)
labels each visited state with its action distribution. An auxiliary actor head on the same
GRU is trained by imitation only; where even it cannot match the teacher (the teacher uses
information the student's observation lacks) imitation is down-weighted in favour of RL::

    w(s) = exp(-alpha * KL(teacher || aux)(s))          (not differentiated)
    loss = mean_s[w(s) CE(teacher, pi)(s) + (1 - w(s)) PPO(s)]
           + w_rl (vf_coef * value loss - ent_coef * entropy) + mean_s CE(teacher, aux)(s)

``alpha`` is ``--set method.alpha=VALUE``; PPO's reward is the paper's ``-1[overlap] -
1[offroad]``; the logged episodes only warm the GRU up. The value and entropy terms carry
BC-RL's ``w_RL``: the returns are not normalised, and at weight 1 the value loss's gradient took
almost all of the clipped update.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from igdrivsim.core.learn import (
    entropy,
    kl_divergence,
    log_prob,
    masked_mean,
    soft_cross_entropy,
    surrogate_terms,
    value_loss,
)
from igdrivsim.core.params import AdvisorParams
from igdrivsim.errors import ConfigError
from igdrivsim.names import LEARNED
from igdrivsim.training.methods import Method, register_method


@dataclass(frozen=True)
class Params(AdvisorParams):
    """``alpha``, shared with the maze (:class:`igdrivsim.core.params.AdvisorParams`)."""

    def __post_init__(self):
        if not 0.0 <= self.alpha < float("inf"):
            raise ConfigError(f"method.alpha must be finite and >= 0, got {self.alpha}")


def loss(spec, out, batch):
    roll, mask, teacher = out["rollout"], batch["valid"], batch["teacher_logp"]
    ce = soft_cross_entropy(teacher, roll.logits).sum(-1)
    weight = jnp.exp(-spec.params.alpha * jax.lax.stop_gradient(
        kl_divergence(teacher, roll.aux_logits).sum(-1)))
    pg = surrogate_terms(log_prob(roll.logits, batch["actions"]).sum(-1), batch["log_probs"],
                         batch["advantages"], spec.loss.clip_eps)
    vl = value_loss(roll.values, batch["returns"], mask)
    ent = masked_mean(entropy(roll.logits).sum(-1), mask)
    aux_ce = masked_mean(soft_cross_entropy(teacher, roll.aux_logits).sum(-1), mask)
    total = (masked_mean(weight * ce + (1.0 - weight) * pg, mask)
             + spec.loss.w_rl * (spec.loss.vf_coef * vl - spec.loss.ent_coef * ent) + aux_ce)
    return total, {"teacher_ce": masked_mean(ce, mask), "aux_teacher_ce": aux_ce,
                   "imitation_weight": masked_mean(weight, mask), "value_loss": vl,
                   "policy_entropy": ent, "policy_loss": masked_mean(pg, mask)}


register_method(Method("advisor", *LEARNED["advisor"], loss, episodes=("rollout",),
                       teacher=True, aux_head=True, params=Params(), reports="teacher_ce"))
