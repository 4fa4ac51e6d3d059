"""DAgger with a privileged teacher in the maze (Ross et al. 2011; the idea, our code).

Iteration 0: the full-observation teacher drives and labels (plain BC data). Every later
iteration: the partial-observation student drives, the teacher, running alongside on the full
observation of the same states, labels them (:func:`maze.rollout.run_labelled`); the new
streams are appended to a preallocated buffer (``iterations`` slots) and the student is trained
on the aggregate for ``steps_per_iteration`` minibatches of whole streams drawn uniformly from
the filled slots. Labels are the teacher's action distributions (soft cross-entropy). Pure and
single-seed.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from igdrivsim.core.learn import clipped_adam, sgd_steps, soft_cross_entropy
from maze.env import MazeParams
from maze.network import GRUPolicy
from maze.rollout import run_labelled, start_stream


@dataclasses.dataclass(frozen=True)
class DAggerConfig:
    iterations: int = 8
    num_envs: int = 64
    num_steps: int = 128
    steps_per_iteration: int = 64  # gradient steps on the aggregate after each collection
    batch_streams: int = 16
    lr: float = 3e-3
    max_grad_norm: float = 1.0

    @property
    def steps_per_collection(self) -> int:
        return self.num_envs * self.num_steps


@struct.dataclass
class DAggerState:
    params: dict
    opt_state: optax.OptState
    key: jax.Array
    obs: jax.Array  # f32[I, T, E, D], the student's observations, slot by slot
    first: jax.Array  # bool[I, T, E]
    label: jax.Array  # f32[I, T, E, A], the teacher's log-probabilities
    filled: jax.Array  # int32, slots holding data


def make_dagger(model: GRUPolicy, teacher: GRUPolicy, params: MazeParams, cfg: DAggerConfig):
    """``(init, iteration)``: ``iteration(state, teacher_params) -> (state, metrics)`` collects
    one slot and trains; metrics: ``loss_before`` / ``loss_after`` (CE on the aggregate's
    sampled minibatches, first and last step) and ``dataset`` (transitions held)."""
    tx = clipped_adam(cfg.max_grad_norm)
    d, a = params.obs_dim, model.num_actions
    shape = (cfg.iterations, cfg.num_steps, cfg.num_envs)

    def init(key: jax.Array, net_params) -> DAggerState:
        return DAggerState(net_params, tx.init(net_params), key, jnp.zeros((*shape, d)),
                           jnp.zeros(shape, bool), jnp.zeros((*shape, a)),
                           jnp.zeros((), jnp.int32))

    def loss_fn(net_params, minibatch):
        obs, first, label = minibatch
        h0 = jnp.zeros((obs.shape[1], model.hidden))
        logits = model.apply(net_params, h0, obs, first)[1]
        loss = soft_cross_entropy(label, logits).mean()
        return loss, loss

    def iteration(state: DAggerState, teacher_params):
        key, key_env, key_roll, key_train = jax.random.split(state.key, 4)
        stream = start_stream(key_env, cfg.num_envs, model.hidden, params)
        _, _, traj = run_labelled(model, state.params, teacher, teacher_params, stream,
                                  jnp.zeros((cfg.num_envs, teacher.hidden)), key_roll,
                                  cfg.num_steps, params, teacher_drives=state.filled == 0)
        slot = state.filled
        obs = state.obs.at[slot].set(traj.obs)
        first = state.first.at[slot].set(traj.first)
        label = state.label.at[slot].set(traj.label)
        filled = slot + 1

        def draw(data, key):  # batch_streams streams drawn from the filled slots, [T, B, ...]
            k_slot, k_env = jax.random.split(key)
            slots = jax.random.randint(k_slot, (cfg.batch_streams,), 0, filled)
            envs = jax.random.randint(k_env, (cfg.batch_streams,), 0, cfg.num_envs)
            return jax.tree.map(lambda x: jnp.swapaxes(x[slots, :, envs], 0, 1), data)

        net_params, opt_state, losses = sgd_steps(
            state.params, state.opt_state, (obs, first, label), loss_fn, tx, cfg.lr,
            jax.random.split(key_train, cfg.steps_per_iteration), select=draw)
        k = max(1, cfg.steps_per_iteration // 8)
        metrics = {"loss_before": losses[:k].mean(), "loss_after": losses[-k:].mean(),
                   "dataset": filled * cfg.steps_per_collection,
                   "return": traj.reward.sum() / jnp.maximum(traj.done.sum(), 1)}
        return state.replace(params=net_params, opt_state=opt_state, key=key, obs=obs,
                             first=first, label=label, filled=filled), metrics

    return init, iteration
