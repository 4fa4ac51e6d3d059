"""Rollouts labelled by a privileged teacher (DAgger, BC+PPO, ADVISOR), pure and single-seed.

The student acts on the *partial* observation; the teacher (the full-observation RL expert, a
GRU too) runs alongside on the *full* observation of the same states, its memory reset at the
same episode starts, and its action distribution is recorded as the label. ``teacher_drives``
(a bool array) lets the teacher choose the actions instead (DAgger's first iteration).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from maze import env as maze_env
from maze.env import MazeParams
from maze.network import GRUPolicy
from maze.rollout import Stream


class Labelled(NamedTuple):
    obs: jax.Array  # f32[T, E, D], the student's (partial) observation
    teacher_obs: jax.Array  # f32[T, E, D], the teacher's (full) observation
    first: jax.Array  # bool[T, E]
    action: jax.Array  # int32[T, E], the action taken
    log_prob: jax.Array  # f32[T, E], the student's log-probability of it
    value: jax.Array  # f32[T, E], the student's value
    reward: jax.Array  # f32[T, E]
    done: jax.Array  # bool[T, E]
    length: jax.Array  # int32[T, E], episode length where done
    teacher_logp: jax.Array  # f32[T, E, A], the teacher's log-probabilities (the label)


def _observe(state, params, partial: bool):
    return jax.vmap(maze_env.observe, (0, None, None))(state, params, partial)


def run_labelled(student: GRUPolicy, student_params, teacher: GRUPolicy, teacher_params,
                 stream: Stream, teacher_h: jax.Array, key: jax.Array, num_steps: int,
                 params: MazeParams, teacher_drives=False
                 ) -> tuple[Stream, jax.Array, Labelled]:
    """``num_steps`` steps in every env (auto-reset); returns the streams, the teacher's memory
    and the ``[T, E, ...]`` transitions."""
    drives = jnp.asarray(teacher_drives, bool)

    def one(carry, key):
        stream, th = carry
        obs = _observe(stream.state, params, True)
        t_obs = _observe(stream.state, params, False)
        out = student.apply(student_params, stream.h, obs[None], stream.first[None])
        h, logits, value = out[0], out[1][0], out[2][0]
        th, t_logits, _ = teacher.apply(teacher_params, th, t_obs[None], stream.first[None])[:3]
        t_logp = jax.nn.log_softmax(t_logits[0])
        key_s, key_t = jax.random.split(key)
        action = jnp.where(drives, jax.random.categorical(key_t, t_logp),
                           jax.random.categorical(key_s, logits))
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], -1)[:, 0]
        length = stream.state.time + 1
        state, reward, done = jax.vmap(maze_env.auto_step, (0, 0, None))(stream.state, action,
                                                                          params)
        tr = Labelled(obs, t_obs, stream.first, action, log_prob, value, reward, done, length,
                      t_logp)
        return (Stream(state=state, first=done, h=h), th), tr

    (stream, teacher_h), traj = jax.lax.scan(one, (stream, teacher_h),
                                             jax.random.split(key, num_steps))
    return stream, teacher_h, traj


def soft_cross_entropy(label_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """Per-state ``-sum_a p_teacher(a) log p_student(a)`` (same minimiser as the KL)."""
    return -(jnp.exp(label_logp) * jax.nn.log_softmax(logits)).sum(-1)


def kl(label_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """Per-state ``KL(teacher || student)``."""
    return (jnp.exp(label_logp) * (label_logp - jax.nn.log_softmax(logits))).sum(-1)
