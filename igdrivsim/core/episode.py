"""The one episode runner: an actor and a pure environment step in a ``lax.scan``.

The runner needs only ``env_step(state, action) -> (state, out)`` (gymnax-style: the maze's
:mod:`maze.env`, the simulator's :mod:`igdrivsim.simulator.state`). An :class:`Actor` is
Waymax's ``init(state, key) -> carry`` / ``step(state, carry, key) -> (action, carry, info)``
split; it observes the state itself and ``info`` (any pytree, usually a :class:`StepInfo`) is
recorded per step. ``jit``- and ``vmap``-able, for a single or a batched state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

StepFn = Callable[[Any, Any, jax.Array], tuple[Any, Any, Any]]
EnvStep = Callable[[Any, Any], tuple[Any, Any]]


def no_carry(state: Any, key: jax.Array) -> None:
    """The ``init`` of an actor without memory."""


class Actor(NamedTuple):
    """Two pure functions (see the module docstring); calling the actor calls ``step``."""

    step: StepFn
    init: Callable[[Any, jax.Array], Any] = no_carry

    def __call__(self, state: Any, carry: Any, key: jax.Array):
        return self.step(state, carry, key)


class StepInfo(NamedTuple):
    """What an observing actor reports per step besides its action (``None``: not computed)."""

    observation: Any = None  # what the actor acted on
    value: jax.Array | None = None  # f32[...], the critic's estimate
    log_prob: jax.Array | None = None  # f32[...], log pi(action)
    extras: Any = None  # anything else (the driving policy's chosen levels)


class Step(NamedTuple):
    """One step of :func:`run_episode`, stacked on a leading time axis ``[T]``."""

    action: Any  # the action applied
    info: Any  # the actor's ``info``
    out: Any  # the environment step's ``out``


def run_episode(env_step: EnvStep, actor: Actor, state: Any, key: jax.Array, num_steps: int,
                carry: Any = None, record: Callable[[Step], Any] = lambda step: step
                ) -> tuple[Any, Any, Any]:
    """``(final state, final carry, record [T, ...])`` of ``num_steps`` steps from ``state``;
    ``carry`` ``None``: ``actor.init(state, key)``; the actor's key at step ``t`` is
    ``split(key, num_steps)[t]``; ``record(Step)``: what is kept of each step."""
    if carry is None:
        carry = actor.init(state, key)

    def body(c, k):
        s, ac = c
        action, ac, info = actor.step(s, ac, k)
        s, out = env_step(s, action)
        return (s, ac), record(Step(action, info, out))

    (final, carry), steps = jax.lax.scan(body, (state, carry), jax.random.split(key, num_steps))
    return final, carry, steps
