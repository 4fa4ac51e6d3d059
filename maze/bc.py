"""Behavioural cloning of a recurrent expert (paper Fig. 2), one seed at a time (``vmap`` outside).

Data: the expert acts on *its own* observation in ``num_envs`` continuing streams of
``num_steps`` steps (auto-reset), and the label is the action it *sampled* (as in the paper);
each transition stores the imitator's observation of the same state. Every stream starts at a
fresh episode and the GRU state is zeroed at each episode start, so training unrolls whole
streams from a zero state and sees exactly the episodes the expert produced.

Training: NLL of the labels, Adam (constant learning rate: a cosine decay over 40 epochs gave
the same returns), minibatches of whole streams. The expert's and the
imitator's observation kinds are arrays (True = partial), so one compiled function serves every
BC curve and the study ``vmap``s over curves and seeds at once.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from igdrivsim.core.learn import clipped_adam, log_prob, sgd_epochs
from maze.env import MazeParams
from maze.network import GRUPolicy
from maze.rollout import run_stream, start_stream


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """Dataset size and optimiser of BC (its own learning rate). The study uses 32 minibatches
    of whole streams (two each) for 6 epochs: more, smaller Adam steps learn faster per epoch
    (16 minibatches: 6 epochs stopped BC partial -> partial at 86% of partial RL's return, 12 at
    93%); 32 x 6 takes the 192 steps of 16 x 12 at half the compute."""

    num_envs: int = 64
    num_steps: int = 512
    epochs: int = 30
    num_minibatches: int = 4
    lr: float = 3e-3
    max_grad_norm: float = 1.0

    @property
    def dataset_size(self) -> int:
        return self.num_envs * self.num_steps


class Demos(NamedTuple):
    obs: jax.Array  # f32[T, E, D], the imitator's observation
    first: jax.Array  # bool[T, E], episode start
    action: jax.Array  # int32[T, E], the expert's sampled action


@struct.dataclass
class BCState:
    params: dict
    opt_state: optax.OptState
    key: jax.Array
    demos: Demos


def collect_demos(model: GRUPolicy, expert_params, key: jax.Array, cfg: BCConfig,
                  params: MazeParams, expert_partial, imitator_partial) -> Demos:
    """Expert rollouts on ``expert_partial`` observations, stored as the imitator sees them."""
    key_env, key_act = jax.random.split(key)
    stream = start_stream(key_env, cfg.num_envs, model.hidden, params)
    _, traj = run_stream(model, expert_params, stream, key_act, cfg.num_steps, params,
                         jnp.asarray(expert_partial, bool), jnp.asarray(imitator_partial, bool))
    return Demos(traj.other_obs, traj.first, traj.action)


def nll(model: GRUPolicy, net_params, demos: Demos) -> jax.Array:
    """Mean negative log-likelihood of the expert's actions under the imitator."""
    h0 = jnp.zeros((demos.obs.shape[1], model.hidden))
    _, logits, _ = model.apply(net_params, h0, demos.obs, demos.first)
    return -log_prob(logits, demos.action).mean()


def take_streams(data, idx):
    """The streams ``idx`` of time-major ``[T, E, ...]`` arrays."""
    return jax.tree.map(lambda x: x[:, idx], data)


def make_bc(model: GRUPolicy, cfg: BCConfig, chunk_epochs: int):
    """``(init, train_chunk)``: ``train_chunk`` runs ``chunk_epochs`` epochs, returns the loss."""
    tx = clipped_adam(cfg.max_grad_norm)

    def loss_fn(net_params, demos: Demos):
        loss = nll(model, net_params, demos)
        return loss, loss

    def init(key: jax.Array, net_params, demos: Demos) -> BCState:
        return BCState(net_params, tx.init(net_params), key, demos)

    def train_chunk(state: BCState):
        def next_key(key, _):
            key, key_perm = jax.random.split(key)
            return key, key_perm

        key, epoch_keys = jax.lax.scan(next_key, state.key, None, length=chunk_epochs)
        net_params, opt_state, losses = sgd_epochs(
            state.params, state.opt_state, state.demos, loss_fn, tx, epoch_keys,
            cfg.num_minibatches, cfg.lr, size=cfg.num_envs, select=take_streams)
        return state.replace(params=net_params, opt_state=opt_state, key=key), losses[-1].mean()

    return init, train_chunk
