"""Recurrent PPO (PureJaxRL style): rollout, GAE and minibatch epochs in one jitted function.

The rollout is the shared runner (:mod:`maze.rollout`), GAE and the loss terms the shared ones
(:mod:`igdrivsim.core.learn`) and the minibatch epochs the shared loop
(:func:`igdrivsim.core.learn.sgd_epochs`), as in the driving benchmark's BC-RL.

``make_ppo(...)`` returns ``init(key, net_params, partial, total_updates) -> PPOState`` and
``train_chunk(PPOState) -> (PPOState, metrics)``, a ``lax.scan`` over ``chunk_updates`` PPO
updates; both are pure and single-seed, so the study ``vmap``s them over seeds and calls the chunk
repeatedly (one progress-bar tick per chunk). The observation kind (``partial``) and the length
of the learning-rate schedule live in the state as arrays, so one compiled function trains both
the full- and the partial-observation agent.
Minibatches split the environments, so every minibatch holds whole sequences and the GRU is
unrolled from the hidden state it had at the start of the rollout.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from igdrivsim.core.learn import (
    clipped_adam,
    clipped_value_loss,
    entropy,
    gae,
    log_prob,
    normalize,
    sgd_epochs,
    surrogate_terms,
)
from igdrivsim.core.params import PPOParams
from maze.env import MazeParams, observe
from maze.network import GRUPolicy
from maze.rollout import Stream, run_stream, start_stream


@dataclasses.dataclass(frozen=True)
class PPOConfig(PPOParams):
    """Paper (PureJaxRL) defaults except ``lr``, ``update_epochs`` and ``num_minibatches``: one
    pass of 8 minibatches per rollout at lr 1.2e-2. The partial agent (10 seeds, GRU-64, linear
    decay to 0, measured; "rose": over the last quarter of the updates): 4 epochs x 4 minibatches
    at 2e-3 reached 6.16 in 80 updates (rose 0.25); 2 x 4 at 8e-3 7.35 in 120 (rose 0.25); 1 x 8
    at 8e-3 8.02 in 480 updates (rose 0.05), at 1.2e-2 7.99 in 320 (rose 0.03) and 7.81 in 280
    (rose 0.15); 16 minibatches at 1.2e-2 7.69 in 240 (rose 0.33); 64-step rollouts 6.63 in 320
    (rose 0.23). At GRU-32, the study's width (seeds 0-4, 1 x 8 at 1.2e-2; "rose": from half the
    updates, the study's plateau test under the decay, :func:`maze.extended.plateau_start`):
    7.74 in 320 updates (rose 0.32), 8.07 in 480 (rose 0.14), 8.09 in 520 (rose 0.18), 8.10 in
    640 (rose 0.08); 32 envs x 4 minibatches 7.92 in 640 (rose 0.43); 96-step rollouts 7.97 in
    640 (rose 0.20). A PPO update is compute-bound (the GRU's products),
    so the updates are the study's cost. ``gamma``, ``gae_lambda``, ``clip_eps``, ``ent_coef``
    and ``vf_coef`` are the driving benchmark's PPO parameters
    (:class:`igdrivsim.core.params.PPOParams`, their defaults)."""

    lr: float = 1.2e-2
    anneal_lr: bool = True
    num_envs: int = 64
    num_steps: int = 128
    update_epochs: int = 1
    num_minibatches: int = 8
    max_grad_norm: float = 0.5

    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.num_steps


@struct.dataclass
class PPOState:
    params: dict
    opt_state: optax.OptState
    stream: Stream
    key: jax.Array
    partial: jax.Array  # bool, the agent observes the imitator's (partial) observation
    update: jax.Array  # int32, updates done so far
    total_updates: jax.Array  # int32, length of the linear learning-rate decay


def make_optimizer(max_grad_norm: float):
    """Global-norm clipping then Adam's scaling (PureJaxRL's eps 1e-5); the (annealed) step size
    is the loop's."""
    return clipped_adam(max_grad_norm, eps=1e-5)


def take_envs(data, idx):
    """The streams ``idx`` of ``(h0 [E, H], *arrays [T, E, ...])``: minibatches of whole
    streams, each unrolled from its hidden state at the start of the rollout."""
    h0, *rest = data
    return (h0[idx], *jax.tree.map(lambda x: x[:, idx], rest))


def ppo_terms(logits, value, batch, adv, targets, cfg: PPOConfig):
    """Per-state clipped policy loss, the clipped value loss and the entropy of a minibatch
    (the shared terms of :mod:`igdrivsim.core.learn`; the advantages normalised here)."""
    pg = surrogate_terms(log_prob(logits, batch.action), batch.log_prob, normalize(adv),
                         cfg.clip_eps)
    return (pg, clipped_value_loss(value, batch.value, targets, cfg.clip_eps),
            entropy(logits).mean())


def make_ppo(model: GRUPolicy, params: MazeParams, cfg: PPOConfig, chunk_updates: int):
    """``(init, train_chunk)`` for recurrent PPO (see module docstring)."""
    tx = make_optimizer(cfg.max_grad_norm)

    def init(key: jax.Array, net_params, partial, total_updates) -> PPOState:
        key_env, key = jax.random.split(key)
        return PPOState(net_params, tx.init(net_params),
                        start_stream(key_env, cfg.num_envs, model.hidden, params), key,
                        jnp.asarray(partial, bool), jnp.zeros((), jnp.int32),
                        jnp.asarray(total_updates, jnp.int32))

    def loss_fn(net_params, minibatch):
        h0, batch, adv, targets = minibatch
        _, logits, value = model.apply(net_params, h0, batch.obs, batch.first)
        pg, value_loss, ent = ppo_terms(logits, value, batch, adv, targets, cfg)
        return pg.mean() + cfg.vf_coef * value_loss - cfg.ent_coef * ent, None

    def update(state: PPOState, _):
        key, key_roll, key_perm = jax.random.split(state.key, 3)
        h0 = state.stream.h
        kind = state.partial
        stream, traj = run_stream(model, state.params, state.stream, key_roll, cfg.num_steps,
                                  params, kind)
        last_obs = jax.vmap(observe, (0, None, None))(stream.state, params, kind)
        frac = 1.0 - state.update / state.total_updates if cfg.anneal_lr else 1.0
        lr = cfg.lr * jnp.maximum(frac, 0.0)
        _, _, last_value = model.apply(state.params, stream.h, last_obs[None], stream.first[None])
        adv, targets = gae(traj.value, traj.reward, traj.done, last_value[0], cfg.gamma,
                           cfg.gae_lambda)

        net_params, opt_state, _ = sgd_epochs(
            state.params, state.opt_state, (h0, traj, adv, targets), loss_fn, tx,
            jax.random.split(key_perm, cfg.update_epochs), cfg.num_minibatches, lr,
            size=cfg.num_envs, select=take_envs)
        episodes = traj.done.sum()
        metrics = {
            "return": traj.reward.sum() / jnp.maximum(episodes, 1),
            "length": (traj.length * traj.done).sum() / jnp.maximum(episodes, 1),
            "episodes": episodes,
        }
        return state.replace(params=net_params, opt_state=opt_state, stream=stream, key=key,
                             update=state.update + 1), metrics

    def train_chunk(state: PPOState):
        return jax.lax.scan(update, state, None, length=chunk_updates)

    return init, train_chunk
