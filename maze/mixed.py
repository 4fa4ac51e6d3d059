"""BC+PPO (the paper's remedy) and adaptive weighting (ADVISOR, Weihs et al. 2021) in the maze.

Both train a partial-observation student with recurrent PPO on the maze's own reward while the
full-observation teacher labels every state the student visits
(:func:`maze.rollout.run_labelled`). The per-state loss mixes imitation (soft cross-entropy to
the teacher's action distribution) and the clipped PPO policy term:

* ``adaptive = False`` (BC+PPO): ``w_bc * CE + w_rl * PPO`` (value and entropy terms scaled by
  ``w_rl`` too: the paper's ``w_BC BC + w_RL PPO`` with ``w_BC = 1``, ``w_RL = 0.05``).
* ``adaptive = True`` (ADVISOR, our implementation of the idea): an auxiliary actor head on the
  same GRU trunk is trained by imitation only; where it cannot match the teacher (the teacher
  uses information the student lacks) the imitation weight drops,
  ``w(s) = exp(-alpha * KL(teacher || aux)(s))``, and the loss is
  ``w(s) CE(s) + (1 - w(s)) PPO(s)`` plus the auxiliary head's CE (weights not differentiated).

The mode is an array in the state, so one compiled function trains both methods (``vmap`` over
methods x seeds). Single seed, pure; the study calls ``train_chunk`` repeatedly.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from igdrivsim.core.learn import gae, kl_divergence, sgd_epochs, soft_cross_entropy
from igdrivsim.core.params import AdvisorParams, MixWeights
from maze.env import MazeParams, observe
from maze.network import GRUPolicy
from maze.ppo import PPOConfig, make_optimizer, ppo_terms, take_envs
from maze.rollout import Stream, run_labelled, start_stream


@dataclasses.dataclass(frozen=True)
class MixedConfig(MixWeights, AdvisorParams):
    """BC+PPO's loss weights (the paper's ``w_bc = 1``, ``w_rl = 0.05``) and ADVISOR's
    ``alpha``: the driving benchmark's parameters with their defaults
    (:mod:`igdrivsim.core.params`); the maze study sets its own ``alpha``
    (``maze.study.MAZE_ADVISOR_ALPHA``)."""


@struct.dataclass
class MixedState:
    params: dict
    opt_state: optax.OptState
    stream: Stream
    teacher_h: jax.Array  # f32[E, H], the teacher's memory along the student's streams
    key: jax.Array
    adaptive: jax.Array  # bool, ADVISOR (True) or fixed-weight BC+PPO (False)
    update: jax.Array  # int32
    total_updates: jax.Array  # int32, length of the linear learning-rate decay


def make_mixed(model: GRUPolicy, teacher: GRUPolicy, params: MazeParams, cfg: PPOConfig,
               mix: MixedConfig, chunk_updates: int):
    """``(init, train_chunk)``; ``model`` must have ``aux_head=True``.

    ``train_chunk(state, teacher_params) -> (state, metrics)`` runs ``chunk_updates`` updates;
    metrics per update: ``loss`` (imitation CE of the main head), ``weight`` (mean imitation
    weight), ``return``.
    """
    assert model.aux_head, "the mixed learner needs the auxiliary head"
    tx = make_optimizer(cfg.max_grad_norm)

    def init(key: jax.Array, net_params, adaptive, total_updates) -> MixedState:
        key_env, key = jax.random.split(key)
        return MixedState(net_params, tx.init(net_params),
                          start_stream(key_env, cfg.num_envs, model.hidden, params),
                          jnp.zeros((cfg.num_envs, teacher.hidden)), key,
                          jnp.asarray(adaptive, bool), jnp.zeros((), jnp.int32),
                          jnp.asarray(total_updates, jnp.int32))

    def loss_fn(net_params, minibatch, adaptive):
        h0, batch, adv, targets = minibatch
        _, logits, value, aux = model.apply(net_params, h0, batch.obs, batch.first)
        pg, value_loss, entropy = ppo_terms(logits, value, batch, adv, targets, cfg)
        ce = soft_cross_entropy(batch.label, logits)
        aux_ce = soft_cross_entropy(batch.label, aux)
        w_adv = jnp.exp(-mix.alpha * jax.lax.stop_gradient(kl_divergence(batch.label, aux)))
        w_il = jnp.where(adaptive, w_adv, mix.w_bc)
        w_pg = jnp.where(adaptive, 1.0 - w_adv, mix.w_rl)
        rl_scale = jnp.where(adaptive, 1.0, mix.w_rl)
        loss = ((w_il * ce + w_pg * pg).mean()
                + rl_scale * (cfg.vf_coef * value_loss - cfg.ent_coef * entropy)
                + jnp.where(adaptive, aux_ce.mean(), 0.0))
        return loss, (ce.mean(), w_il.mean())

    def update(carry, _):
        state, teacher_params = carry
        key, key_roll, key_perm = jax.random.split(state.key, 3)
        h0 = state.stream.h
        stream, teacher_h, traj = run_labelled(model, state.params, teacher, teacher_params,
                                               state.stream, state.teacher_h, key_roll,
                                               cfg.num_steps, params)
        last_obs = jax.vmap(observe, (0, None, None))(stream.state, params, True)
        frac = 1.0 - state.update / state.total_updates if cfg.anneal_lr else 1.0
        lr = cfg.lr * jnp.maximum(frac, 0.0)
        last_value = model.apply(state.params, stream.h, last_obs[None], stream.first[None])[2]
        adv, targets = gae(traj.value, traj.reward, traj.done, last_value[0], cfg.gamma,
                           cfg.gae_lambda)

        net_params, opt_state, (ce, weight) = sgd_epochs(
            state.params, state.opt_state, (h0, traj, adv, targets),
            lambda p, mb: loss_fn(p, mb, state.adaptive), tx,
            jax.random.split(key_perm, cfg.update_epochs), cfg.num_minibatches, lr,
            size=cfg.num_envs, select=take_envs)
        episodes = traj.done.sum()
        metrics = {"loss": ce[0].mean(), "weight": weight.mean(),
                   "return": traj.reward.sum() / jnp.maximum(episodes, 1)}
        state = state.replace(params=net_params, opt_state=opt_state, stream=stream,
                              teacher_h=teacher_h, key=key, update=state.update + 1)
        return (state, teacher_params), metrics

    def train_chunk(state: MixedState, teacher_params):
        (state, _), metrics = jax.lax.scan(update, (state, teacher_params), None,
                                           length=chunk_updates)
        return state, metrics

    return init, train_chunk
