"""The maze's actors and episodes on the shared runner (:mod:`igdrivsim.core.episode`).

Pure and single-seed (``vmap`` over seeds outside). The environment state the runner carries is
``(MazeState [E], first [E])``: ``first`` marks an observation that starts an episode, where the
GRU memory (the actor's carry) is zeroed. Three ways through the maze:

* :func:`run_stream`: continuing episodes (auto-reset) of one policy, for PPO and BC's data;
* :func:`run_labelled`: the partial-observation student acts (or the teacher, DAgger's first
  iteration) while the full-observation teacher, a GRU too, runs alongside on the same states
  and labels each with its action distribution (DAgger, BC+PPO, ADVISOR);
* :func:`evaluate`: fresh episodes without reset, for the learning curves.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.core.episode import Actor, StepInfo, run_episode
from igdrivsim.core.learn import log_prob
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
    obs: jax.Array  # f32[T, E, D], observation of the acting policy (the student's, labelled)
    other_obs: jax.Array  # f32[T, E, D], the other kind of the same state (imitator's; teacher's)
    first: jax.Array  # bool[T, E]
    action: jax.Array  # int32[T, E]
    log_prob: jax.Array  # f32[T, E], the (student) policy's log-probability of the action
    value: jax.Array  # f32[T, E]
    reward: jax.Array  # f32[T, E]
    done: jax.Array  # bool[T, E]
    length: jax.Array  # int32[T, E], episode length where done
    label: Any = None  # f32[T, E, A], the teacher's log-probabilities (labelled runs)


def start_stream(key: jax.Array, num_envs: int, hidden: int, params: MazeParams) -> Stream:
    state = jax.vmap(maze_env.reset, (0, None))(jax.random.split(key, num_envs), params)
    return Stream(state=state, first=jnp.ones(num_envs, bool), h=jnp.zeros((num_envs, hidden)))


def _observe(state, params, kind):
    return jax.vmap(maze_env.observe, (0, None, None))(state, params, kind)


def policy_actor(model: GRUPolicy, net_params, params: MazeParams, kind, other_kind=None
                 ) -> Actor:
    """A policy acting on observations of ``kind`` (``"full"``, ``"partial"`` or a boolean
    array, True = partial), sampling its actions; carry: the GRU state ``[E, H]``. Its info's
    extras: ``(the other_kind observation (the acting one when None), first)``."""

    def step(env_state, h, key):
        state, first = env_state[0], env_state[1]
        obs = _observe(state, params, kind)
        other = obs if other_kind is None else _observe(state, params, other_kind)
        h, logits, value = model.apply(net_params, h, obs[None], first[None])[:3]
        logits, value = logits[0], value[0]
        action = jax.random.categorical(key, logits)
        return action, h, StepInfo(obs, value, log_prob(logits, action), (other, first))

    return Actor(step=step)


def labelled_actor(student: GRUPolicy, student_params, teacher: GRUPolicy, teacher_params,
                   params: MazeParams, teacher_drives=False) -> Actor:
    """The partial student and the full teacher on the same states; carry: both GRU states.
    The teacher chooses the actions where ``teacher_drives`` (a bool array). Extras: ``(the
    teacher's observation, first, the teacher's log-probabilities)``."""
    drives = jnp.asarray(teacher_drives, bool)

    def step(env_state, carry, key):
        (state, first), (h, th) = env_state, carry
        obs = _observe(state, params, True)
        t_obs = _observe(state, params, False)
        h, logits, value = student.apply(student_params, h, obs[None], first[None])[:3]
        logits, value = logits[0], value[0]
        th, t_logits, _ = teacher.apply(teacher_params, th, t_obs[None], first[None])[:3]
        t_logp = jax.nn.log_softmax(t_logits[0])
        key_s, key_t = jax.random.split(key)
        action = jnp.where(drives, jax.random.categorical(key_t, t_logp),
                           jax.random.categorical(key_s, logits))
        return action, (h, th), StepInfo(obs, value, log_prob(logits, action),
                                          (t_obs, first, t_logp))

    return Actor(step=step)


def _auto_reset_step(params: MazeParams):
    """The environment step of continuing episodes: ``(state, first) -> (reward, done,
    length)``; an ended episode restarts (the next observation is its first)."""

    def env_step(env_state, action):
        state = env_state[0]
        length = state.time + 1
        state, reward, done = jax.vmap(maze_env.auto_step, (0, 0, None))(state, action, params)
        return (state, done), (reward, done, length)

    return env_step


def _transition(steps, label: bool) -> Transition:
    info = steps.info
    other, first = info.extras[:2]
    return Transition(info.observation, other, first, steps.action, info.log_prob, info.value,
                      *steps.out, label=info.extras[2] if label else None)


def run_stream(model: GRUPolicy, net_params, stream: Stream, key: jax.Array, num_steps: int,
               params: MazeParams, kind, other_kind=None) -> tuple[Stream, Transition]:
    """``num_steps`` sampled actions in every env (auto-reset); transitions are ``[T, E, ...]``.

    ``other_obs`` is the ``other_kind`` observation (the acting one when ``None``)."""
    actor = policy_actor(model, net_params, params, kind, other_kind)
    (state, first), h, steps = run_episode(_auto_reset_step(params), actor,
                                           (stream.state, stream.first), key, num_steps,
                                           carry=stream.h)
    return Stream(state=state, first=first, h=h), _transition(steps, label=False)


def run_labelled(student: GRUPolicy, student_params, teacher: GRUPolicy, teacher_params,
                 stream: Stream, teacher_h: jax.Array, key: jax.Array, num_steps: int,
                 params: MazeParams, teacher_drives=False
                 ) -> tuple[Stream, jax.Array, Transition]:
    """``num_steps`` labelled steps in every env (auto-reset); returns the streams, the
    teacher's memory and the ``[T, E, ...]`` transitions (``other_obs``: the teacher's)."""
    actor = labelled_actor(student, student_params, teacher, teacher_params, params,
                           teacher_drives)
    (state, first), (h, teacher_h), steps = run_episode(
        _auto_reset_step(params), actor, (stream.state, stream.first), key, num_steps,
        carry=(stream.h, teacher_h))
    return Stream(state=state, first=first, h=h), teacher_h, _transition(steps, label=True)


def evaluate(model: GRUPolicy, net_params, key: jax.Array, num_episodes: int,
             params: MazeParams, kind) -> tuple[jax.Array, jax.Array]:
    """Mean return and mean length of ``num_episodes`` fresh episodes (sampled actions).

    The steps run in a ``lax.while_loop`` that stops once every episode has ended (a trained
    full-observation policy needs about 10 of the ``max_steps`` = 200): the same numbers as
    stepping ``max_steps`` times, since an ended episode stays as it ended and earns nothing;
    the actor's key at step ``t`` is ``split(key, max_steps)[t]`` as in :func:`run_episode`.
    """
    key_reset, key_act = jax.random.split(key)
    state = jax.vmap(maze_env.reset, (0, None))(jax.random.split(key_reset, num_episodes), params)
    actor = policy_actor(model, net_params, params, kind)
    keys = jax.random.split(key_act, params.max_steps)

    def live(carry):
        t, _, over = carry[:3]
        return (t < params.max_steps) & ~over.all()

    def body(carry):
        t, state, over, first, h, total, steps = carry
        action, h, _ = actor.step((state, first), h, keys[t])
        nxt, reward, done = jax.vmap(maze_env.step, (0, 0, None))(state, action, params)
        on = ~over
        state = jax.tree.map(
            lambda a, b: jnp.where(on.reshape(on.shape + (1,) * (a.ndim - 1)), a, b), nxt, state)
        return (t + 1, state, over | done, jnp.zeros_like(first), h,
                total + jnp.where(on, reward, 0.0), steps + on)

    start = (jnp.zeros((), jnp.int32), state, jnp.zeros(num_episodes, bool),
             jnp.ones(num_episodes, bool), jnp.zeros((num_episodes, model.hidden)),
             jnp.zeros(num_episodes), jnp.zeros(num_episodes, jnp.int32))
    *_, total, steps = jax.lax.while_loop(live, body, start)
    return total.mean(), steps.mean()
