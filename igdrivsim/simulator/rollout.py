"""The simulator's episode runner (``run_episode``) and the reference actors.

The expert (:func:`expert_action`) is inverse dynamics from the *simulated* SDC pose to its next
logged pose, so the discretised expert corrects its quantisation error at every step; where the
next logged pose is invalid it waits (zero action).

Every closed-loop episode (evaluation, BC-RL's rollout, replay) is :func:`run_episode`: the
runner of :mod:`igdrivsim.core.episode` (an ``Actor`` or a bare ``step`` function) with the
simulator's step. The metrics of step ``k`` are those of the state after the ``k``-th action
(timesteps 11..90), as in Waymax.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from igdrivsim.core import episode
from igdrivsim.core.episode import Actor, StepInfo
from igdrivsim.data.scenario import DT, NUM_STEPS
from igdrivsim.simulator import dynamics
from igdrivsim.simulator.metrics import StepMetrics, reward, step_metrics
from igdrivsim.simulator.state import (
    SdcTrajectory,
    SimParams,
    SimState,
    _take,
    log_sdc_at,
    log_sdc_row,
    sdc_pose,
    step,
)

DEFAULT_PARAMS = SimParams()
PolicyFn = Callable[[SimState, Any, jax.Array], tuple[jax.Array, Any, Any]]


def expert_action(state: SimState, params: SimParams = DEFAULT_PARAMS):
    """``f32[..., 3]``: the (clipped) action that moves the simulated SDC onto its next log pose."""
    _, inverse = dynamics.DYNAMICS[params.dynamics]
    x, y, yaw, _ = sdc_pose(state)
    t1 = jnp.minimum(state.timestep + 1, NUM_STEPS - 1)
    lx, ly, lyaw, lvalid = log_sdc_at(state, t1)
    action = inverse(x, y, yaw, lx, ly, lyaw)
    ok = (lvalid & (state.timestep < NUM_STEPS - 1))[..., None]
    return jnp.where(ok, action, 0.0).astype(jnp.float32)


def expert_discrete_action(state: SimState, params: SimParams = DEFAULT_PARAMS):
    """``int32[..., 3]``: the expert action on the 257-level grid (see ``dynamics.discretize``)."""
    return dynamics.discretize(expert_action(state, params))


class Transition(NamedTuple):
    """One step of an episode, stacked on a leading time axis ``[T]`` (``None``: not asked)."""

    observation: Any  # Observation [T, ..., ...] (observing actors, when requested)
    action: jax.Array  # f32[T, ..., 3], the continuous delta-local action applied
    extras: Any  # the actor's own record (levels for the discretised expert and the policy)
    expert: jax.Array | None  # int32[T, ..., 3], discretised expert levels at the same state
    log_prob: jax.Array | None  # f32[T, ...]
    value: jax.Array | None  # f32[T, ...]
    reward: jax.Array | None  # f32[T, ...], -1[overlap] - 1[offroad] of the state reached
    valid: jax.Array  # bool[T, ...], the logged SDC valid now and next (the action is defined)
    metrics: Any  # metrics_fn(state reached, params), e.g. StepMetrics (with validity)


def action_defined(state: SimState) -> jax.Array:
    """Whether the logged SDC is valid now and at the next step (an expert label exists)."""
    t = state.timestep
    return log_sdc_at(state, t)[3] & log_sdc_at(state, jnp.minimum(t + 1, NUM_STEPS - 1))[3]


def run_episode(state: SimState, actor: Actor | PolicyFn, key: jax.Array,
                params: SimParams = DEFAULT_PARAMS, *, carry: Any = None,
                metrics_fn: Callable | None = step_metrics, observation: bool = False,
                value: bool = False, log_prob: bool = False, expert: bool = False,
                with_reward: bool = False, num_steps: int | None = None
                ) -> tuple[SimState, Transition]:
    """Drive ``num_steps`` (default ``params.num_controlled_steps``) steps from ``state``:
    ``(final_state, Transition)``, time-major, as :func:`igdrivsim.core.episode.run_episode`
    (``carry``, keys); ``metrics_fn(state, params)`` is applied to the state reached; the flags
    ask for the observation, value, log-probability, expert levels and reward."""
    actor = actor if isinstance(actor, Actor) else Actor(step=actor)
    num_steps = params.num_controlled_steps if num_steps is None else num_steps

    def env_step(s, action):
        # the label and the validity belong to the state the action is taken in
        label = expert_discrete_action(s, params) if expert else None
        valid = action_defined(s)
        s = step(s, action, params)
        m = None if metrics_fn is None else metrics_fn(s, params)
        r = None
        if with_reward:  # the simulator's metrics once, when metrics_fn is them too
            r = reward(m if metrics_fn is step_metrics else step_metrics(s, params))
        return s, (label, valid, r, m)

    def record(st: episode.Step) -> Transition:
        info = st.info if isinstance(st.info, StepInfo) else StepInfo(extras=st.info)
        label, valid, r, m = st.out
        return Transition(info.observation if observation else None, st.action, info.extras,
                          label, info.log_prob if log_prob else None,
                          info.value if value else None, r, valid, m)

    final, _, out = episode.run_episode(env_step, actor, state, key, num_steps, carry, record)
    return final, out


def _time_last(tree, batch_ndim: int):
    """Move the scan's leading time axis to position ``batch_ndim``."""
    return jax.tree.map(lambda a: jnp.moveaxis(a, 0, batch_ndim), tree)


def rollout(state: SimState, policy_fn: Actor | PolicyFn, key: jax.Array,
            params: SimParams = DEFAULT_PARAMS, carry: Any = None
            ) -> tuple[SimState, StepMetrics, Any]:
    """:func:`run_episode` with the simulator's metrics, time after the batch dims:
    ``(final_state, per_step_metrics [..., T], extras [..., T, ...])``."""
    final, tr = run_episode(state, policy_fn, key, params, carry=carry)
    batch_ndim = jnp.ndim(state.timestep)
    return final, _time_last(tr.metrics, batch_ndim), _time_last(tr.extras, batch_ndim)


def log_metrics(state: SimState, params: SimParams = DEFAULT_PARAMS) -> StepMetrics:
    """Per-step metrics ``[..., 80]`` of the *logged* SDC over the controlled steps 11..90."""
    row = log_sdc_row(state)
    logged = state.replace(sdc=SdcTrajectory(x=row.x, y=row.y, yaw=row.yaw, vel_x=row.vel_x,
                                             vel_y=row.vel_y, valid=row.valid))
    start = jnp.asarray(state.timestep)
    steps = jnp.arange(1, params.num_controlled_steps + 1, dtype=jnp.int32)

    def one(_, k):
        return None, step_metrics(logged.replace(timestep=start + k), params)

    _, metrics = jax.lax.scan(one, None, steps)
    return _time_last(metrics, jnp.ndim(start))


@functools.cache
def expert_actor(params: SimParams = DEFAULT_PARAMS, discrete: bool = True) -> Actor:
    """The discretised (default) or continuous expert as an actor (extras: its action); one
    object per ``(params, discrete)`` as passed, so jitted callers compile once."""
    def policy(state, carry, key):
        del key
        if discrete:
            idx = expert_discrete_action(state, params)
            return dynamics.undiscretize(idx), carry, idx
        action = expert_action(state, params)
        return action, carry, action

    return Actor(step=policy)


@functools.cache
def constant_velocity_actor(params: SimParams = DEFAULT_PARAMS) -> Actor:
    """Keep the current velocity vector and heading (a simple baseline). Extras: the action."""
    _, inverse = dynamics.DYNAMICS[params.dynamics]

    def policy(state, carry, key):
        del key
        x, y, yaw, valid = sdc_pose(state)
        vx, vy = _take(state.sdc.vel_x, state.timestep), _take(state.sdc.vel_y, state.timestep)
        action = inverse(x, y, yaw, x + vx * DT, y + vy * DT, yaw)
        action = jnp.where(valid[..., None], action, 0.0)
        return action, carry, action

    return Actor(step=policy)


ACTORS: dict[str, Callable[[SimParams], Actor]] = {
    "expert": expert_actor, "constant_velocity": constant_velocity_actor}
