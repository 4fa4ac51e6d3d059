"""Rollouts over the 80 controlled steps with ``lax.scan``, and ready-made actors.

A *policy function* has the signature ``policy_fn(state, carry, key) -> (action, carry, extras)``:
``action`` is the float ``[..., 3]`` delta action applied by :func:`~igdrivsim.simulator.step`,
``carry`` any recurrent state (e.g. a GRU hidden state; ``None`` is fine), and ``extras`` any
pytree recorded at every step (e.g. discrete actions, log-probabilities, observations).

:func:`rollout` works on a single state or on a batched one (leading dims ``...``); it is also
``jit``-able and ``vmap``-able (pass ``policy_fn`` and ``params`` as static arguments, see
:func:`jit_rollout`). Outputs are stacked over time on the axis right after the batch dims:
``StepMetrics [..., 80]``, extras ``[..., 80, ...]``. The metrics of step ``k`` are those of the
state *after* the ``k``-th action (timesteps 11..90), as in Waymax.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from igdrivsim.data.scenario import DT
from igdrivsim.simulator import dynamics
from igdrivsim.simulator.expert import expert_action, expert_discrete_action
from igdrivsim.simulator.metrics import StepMetrics, step_metrics
from igdrivsim.simulator.state import (
    SdcTrajectory,
    SimParams,
    SimState,
    log_sdc_row,
    sdc_pose,
    step,
)

DEFAULT_PARAMS = SimParams()
PolicyFn = Callable[[SimState, Any, jax.Array], tuple[jax.Array, Any, Any]]


def _time_last(tree, batch_ndim: int):
    """Move the scan's leading time axis to position ``batch_ndim``."""
    return jax.tree.map(lambda a: jnp.moveaxis(a, 0, batch_ndim), tree)


def rollout(state: SimState, policy_fn: PolicyFn, key: jax.Array,
            params: SimParams = DEFAULT_PARAMS, carry: Any = None
            ) -> tuple[SimState, StepMetrics, Any]:
    """Run ``params.num_controlled_steps`` steps from ``state`` (normally right after reset).

    ``key`` is split into one key per step, passed to ``policy_fn`` (for a batched state without
    ``vmap``, the policy itself must split it per scenario if it needs independent draws).
    Returns ``(final_state, per_step_metrics [..., T], extras [..., T, ...])``.
    """
    batch_ndim = jnp.ndim(state.timestep)
    keys = jax.random.split(key, params.num_controlled_steps)

    def body(c, k):
        st, pc = c
        action, pc, extras = policy_fn(st, pc, k)
        st = step(st, action, params)
        return (st, pc), (step_metrics(st, params), extras)

    (final, _), (metrics, extras) = jax.lax.scan(body, (state, carry), keys)
    return final, _time_last(metrics, batch_ndim), _time_last(extras, batch_ndim)


def with_logged_sdc(state: SimState) -> SimState:
    """The state with the SDC's simulated trajectory replaced by its log (all 91 steps)."""
    row = log_sdc_row(state)
    return state.replace(sdc=SdcTrajectory(x=row.x, y=row.y, yaw=row.yaw, vel_x=row.vel_x,
                                           vel_y=row.vel_y, valid=row.valid))


def log_metrics(state: SimState, params: SimParams = DEFAULT_PARAMS) -> StepMetrics:
    """Per-step metrics ``[..., 80]`` of the *logged* SDC over the controlled steps 11..90.

    The reference for a replay: a clean log has no overlap and no offroad.
    """
    logged = with_logged_sdc(state)
    start = jnp.asarray(state.timestep)
    steps = jnp.arange(1, params.num_controlled_steps + 1, dtype=jnp.int32)

    def one(_, k):
        return None, step_metrics(logged.replace(timestep=start + k), params)

    _, metrics = jax.lax.scan(one, None, steps)
    return _time_last(metrics, jnp.ndim(start))


def jit_rollout(policy_fn: PolicyFn, params: SimParams = DEFAULT_PARAMS):
    """A jitted ``f(state, key, carry=None)`` for a fixed policy and params (cached per pair)."""
    return _jit_rollout(policy_fn, params)


@functools.cache
def _jit_rollout(policy_fn: PolicyFn, params: SimParams):
    return jax.jit(lambda state, key, carry=None: rollout(state, policy_fn, key, params, carry))


def expert_actor(params: SimParams = DEFAULT_PARAMS, discrete: bool = True) -> PolicyFn:
    """The expert as a policy: the discretised expert (default) or the continuous one.

    Extras: the discrete action ``int32[..., 3]`` (or the continuous ``f32[..., 3]``). The same
    ``(params, discrete)`` always gives the same function object, so jitted callers that take
    it as a static argument compile once.
    """
    return _expert_actor(params, discrete)


@functools.cache
def _expert_actor(params: SimParams, discrete: bool) -> PolicyFn:
    def policy(state, carry, key):
        del key
        if discrete:
            idx = expert_discrete_action(state, params)
            return dynamics.undiscretize(idx), carry, idx
        action = expert_action(state, params)
        return action, carry, action

    return policy


def constant_velocity_actor(params: SimParams = DEFAULT_PARAMS) -> PolicyFn:
    """Keep the current velocity vector and heading (a simple baseline). Extras: the action."""
    return _constant_velocity_actor(params)


@functools.cache
def _constant_velocity_actor(params: SimParams) -> PolicyFn:
    _, inverse = dynamics.DYNAMICS[params.dynamics]

    def policy(state, carry, key):
        del key
        x, y, yaw, valid = sdc_pose(state)
        t = state.timestep[..., None]
        vx = jnp.take_along_axis(state.sdc.vel_x, t, axis=-1)[..., 0]
        vy = jnp.take_along_axis(state.sdc.vel_y, t, axis=-1)[..., 0]
        action = inverse(x, y, yaw, x + vx * DT, y + vy * DT, yaw)
        action = jnp.where(valid[..., None], action, 0.0)
        return action, carry, action

    return policy


ACTORS = {"expert": expert_actor, "constant_velocity": constant_velocity_actor}
