"""Policy rollouts shared by PPO, BC and evaluation (pure, single-seed; vmap over seeds outside)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from maze import env as maze_env
from maze.env import MazeParams
from maze.network import GRUPolicy


@struct.dataclass
class Stream:
    """A batch of continuing episodes (auto-reset) and the policy's memory."""

    state: maze_env.MazeState  # [E]
    first: jax.Array  # bool[E], the current observation starts an episode
    h: jax.Array  # f32[E, H]


class Transition(NamedTuple):
    obs: jax.Array  # f32[E, D], observation of the acting policy
    other_obs: jax.Array  # f32[E, D], the other observation kind (imitator's, for BC labels)
    first: jax.Array  # bool[E]
    action: jax.Array  # int32[E]
    log_prob: jax.Array  # f32[E]
    value: jax.Array  # f32[E]
    reward: jax.Array  # f32[E]
    done: jax.Array  # bool[E]
    length: jax.Array  # int32[E], episode length where done


def start_stream(key: jax.Array, num_envs: int, hidden: int, params: MazeParams) -> Stream:
    state = jax.vmap(maze_env.reset, (0, None))(jax.random.split(key, num_envs), params)
    return Stream(state=state, first=jnp.ones(num_envs, bool), h=jnp.zeros((num_envs, hidden)))


def _observe(state, params, kind):
    return jax.vmap(maze_env.observe, (0, None, None))(state, params, kind)


def run_stream(model: GRUPolicy, net_params, stream: Stream, key: jax.Array, num_steps: int,
               params: MazeParams, kind, other_kind=None) -> tuple[Stream, Transition]:
    """``num_steps`` sampled actions in every env (auto-reset); transitions are ``[T, E, ...]``.

    ``kind`` / ``other_kind``: ``"full"``, ``"partial"`` or a boolean array (True = partial);
    ``other_obs`` is the ``other_kind`` observation (the acting one when ``None``).
    """

    def one(carry, key):
        stream = carry
        obs = _observe(stream.state, params, kind)
        other = obs if other_kind is None else _observe(stream.state, params, other_kind)
        h, logits, value = model.apply(net_params, stream.h, obs[None], stream.first[None])
        logits, value = logits[0], value[0]
        action = jax.random.categorical(key, logits)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], -1)[:, 0]
        length = stream.state.time + 1
        state, reward, done = jax.vmap(maze_env.auto_step, (0, 0, None))(stream.state, action,
                                                                          params)
        tr = Transition(obs, other, stream.first, action, log_prob, value, reward, done, length)
        return Stream(state=state, first=done, h=h), tr

    return jax.lax.scan(one, stream, jax.random.split(key, num_steps))


def evaluate(model: GRUPolicy, net_params, key: jax.Array, num_episodes: int,
             params: MazeParams, kind) -> tuple[jax.Array, jax.Array]:
    """Mean return and mean length of ``num_episodes`` fresh episodes (sampled actions)."""
    key_reset, key_act = jax.random.split(key)
    state = jax.vmap(maze_env.reset, (0, None))(jax.random.split(key_reset, num_episodes), params)
    zeros = jnp.zeros(num_episodes)
    init = (state, jnp.zeros((num_episodes, model.hidden)), jnp.zeros(num_episodes, bool), zeros,
            zeros, key_act)

    def cond(carry):
        return jnp.any(~carry[2])

    def body(carry):
        state, h, done, ret, length, key = carry
        key, sub = jax.random.split(key)
        obs = _observe(state, params, kind)
        h, logits, _ = model.apply(net_params, h, obs[None], (state.time == 0)[None])
        action = jax.random.categorical(sub, logits[0])
        nxt, reward, now_done = jax.vmap(maze_env.step, (0, 0, None))(state, action, params)
        live = ~done
        state = jax.tree.map(
            lambda a, b: jnp.where(live.reshape(live.shape + (1,) * (a.ndim - 1)), a, b),
            nxt, state)
        ret = ret + jnp.where(live, reward, 0.0)
        length = length + live
        return state, h, done | now_done, ret, length, key

    _, _, _, ret, length, _ = jax.lax.while_loop(cond, body, init)
    return ret.mean(), length.mean()
