"""Recurrent PPO (PureJaxRL style): rollout, GAE and minibatch epochs in one jitted function.

``make_ppo(...)`` returns ``init(key) -> PPOState`` and ``train_chunk(PPOState) -> (PPOState,
metrics)``, a ``lax.scan`` over ``updates`` PPO updates; both are pure and single-seed, so the
study ``vmap``s them over seeds and calls the chunk repeatedly (one progress-bar tick per chunk).
Minibatches split the environments, so every minibatch holds whole sequences and the GRU is
unrolled from the hidden state it had at the start of the rollout.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from maze.env import MazeParams, observe
from maze.network import GRUPolicy
from maze.rollout import Stream, run_stream, start_stream


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Paper (PureJaxRL) defaults except ``lr`` (1e-3: at 2.5e-4 the partial agent stalls)."""

    lr: float = 1e-3
    anneal_lr: bool = True
    num_envs: int = 64
    num_steps: int = 128
    update_epochs: int = 4
    num_minibatches: int = 4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
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


def make_optimizer(lr: float, max_grad_norm: float, total_updates: int | None = None):
    """Adam with global-norm clipping; linear decay to 0 over ``total_updates`` when given."""
    schedule = optax.linear_schedule(lr, 0.0, total_updates) if total_updates else lr
    return optax.chain(optax.clip_by_global_norm(max_grad_norm),
                       optax.adam(schedule, eps=1e-5))


def gae(values, rewards, dones, last_value, gamma, lam):
    """Generalised advantage estimates and returns (episode ends cut the bootstrap)."""

    def back(carry, xs):
        adv, next_value = carry
        value, reward, done = xs
        delta = reward + gamma * next_value * (1.0 - done) - value
        adv = delta + gamma * lam * (1.0 - done) * adv
        return (adv, value), adv

    _, adv = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value),
                          (values, rewards, dones.astype(jnp.float32)), reverse=True)
    return adv, adv + values


def make_ppo(model: GRUPolicy, params: MazeParams, kind: str, cfg: PPOConfig,
             total_updates: int, chunk_updates: int):
    """``(init, train_chunk)`` for PPO on observation ``kind`` (see module docstring)."""
    tx = make_optimizer(cfg.lr, cfg.max_grad_norm,
                        total_updates * cfg.update_epochs * cfg.num_minibatches
                        if cfg.anneal_lr else None)

    def init(key: jax.Array, net_params) -> PPOState:
        key_env, key = jax.random.split(key)
        return PPOState(net_params, tx.init(net_params),
                        start_stream(key_env, cfg.num_envs, model.hidden, params), key)

    def loss_fn(net_params, h0, batch, adv, targets):
        _, logits, value = model.apply(net_params, h0, batch.obs, batch.first)
        log_p = jax.nn.log_softmax(logits)
        new_log_prob = jnp.take_along_axis(log_p, batch.action[..., None], -1)[..., 0]
        ratio = jnp.exp(new_log_prob - batch.log_prob)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        policy_loss = -jnp.minimum(ratio * adv,
                                   jnp.clip(ratio, 1 - cfg.clip_eps, 1 + cfg.clip_eps) * adv).mean()
        v_clipped = batch.value + jnp.clip(value - batch.value, -cfg.clip_eps, cfg.clip_eps)
        value_loss = 0.5 * jnp.maximum((value - targets) ** 2, (v_clipped - targets) ** 2).mean()
        entropy = -(jnp.exp(log_p) * log_p).sum(-1).mean()
        return policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy

    grad_fn = jax.grad(loss_fn)

    def update(state: PPOState, _):
        key, key_roll, key_perm = jax.random.split(state.key, 3)
        h0 = state.stream.h
        stream, traj = run_stream(model, state.params, state.stream, key_roll, cfg.num_steps,
                                  params, kind)
        last_obs = jax.vmap(observe, (0, None, None))(stream.state, params, kind)
        _, _, last_value = model.apply(state.params, stream.h, last_obs[None], stream.first[None])
        adv, targets = gae(traj.value, traj.reward, traj.done, last_value[0], cfg.gamma,
                           cfg.gae_lambda)

        def epoch(carry, key):
            net_params, opt_state = carry
            perm = jax.random.permutation(key, cfg.num_envs).reshape(cfg.num_minibatches, -1)

            def minibatch(carry, idx):
                net_params, opt_state = carry
                take = lambda x: x[:, idx]  # noqa: E731  (env axis is 1)
                grads = grad_fn(net_params, h0[idx], jax.tree.map(take, traj), take(adv),
                                take(targets))
                updates, opt_state = tx.update(grads, opt_state, net_params)
                return (optax.apply_updates(net_params, updates), opt_state), None

            return jax.lax.scan(minibatch, (net_params, opt_state), perm)[0], None

        (net_params, opt_state), _ = jax.lax.scan(
            epoch, (state.params, state.opt_state), jax.random.split(key_perm, cfg.update_epochs))
        episodes = traj.done.sum()
        metrics = {
            "return": traj.reward.sum() / jnp.maximum(episodes, 1),
            "length": (traj.length * traj.done).sum() / jnp.maximum(episodes, 1),
            "episodes": episodes,
        }
        return PPOState(net_params, opt_state, stream, key), metrics

    def train_chunk(state: PPOState):
        return jax.lax.scan(update, state, None, length=chunk_updates)

    return init, train_chunk
