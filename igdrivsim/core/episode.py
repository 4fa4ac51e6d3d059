"""The one episode runner: an actor and a pure environment step in a ``lax.scan``.

Environments are gymnax-style: pure ``reset`` / ``step`` functions over an immutable state (the
maze's :mod:`maze.env`, the driving simulator's :mod:`igdrivsim.simulator.state`). The runner
needs only a step, closed over the environment's parameters::

    env_step(state, action) -> (state, out)   # out: what the step reports (reward, done, ...)

An :class:`Actor` is two pure functions (Waymax's ``init`` / ``select_action`` split):

* ``init(state, key) -> carry``: the actor's memory before the first step (a GRU state);
* ``step(state, carry, key) -> (action, carry, info)``: the actor *observes the state itself*
  (what it may see is its own observation model: the maze's full or partial view, a driving
  observation setting), and ``info`` is any pytree recorded per step, usually a
  :class:`StepInfo`.

:func:`run_episode` returns the final state and carry and the time-major record of every step,
as PureJaxRL's transition tuple is the only interface between rollout and loss. It works on a
single state or a batched one (the actor and the step then act on the whole batch) and is
``jit``- and ``vmap``-able.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

StepFn = Callable[[Any, Any, jax.Array], tuple[Any, Any, Any]]
EnvStep = Callable[[Any, Any], tuple[Any, Any]]


def no_carry(state: Any, key: jax.Array) -> None:
    """The ``init`` of an actor without memory."""
    del state, key
    return None


class Actor(NamedTuple):
    """``init(state, key) -> carry`` and ``step(state, carry, key) -> (action, carry, info)``,
    pure functions (see the module docstring). Calling the actor calls ``step``."""

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
    """``num_steps`` steps of ``actor`` in ``env_step`` from ``state``.

    ``carry``: the actor's initial memory (``None``: ``actor.init(state, key)``). The actor's
    key at step ``t`` is ``split(key, num_steps)[t]``. ``record(Step)``: what is kept of each
    step (default all; what it drops is never stacked). Returns ``(final state, final carry,
    record [T, ...])``.
    """
    if carry is None:
        carry = actor.init(state, key)

    def body(c, k):
        s, ac = c
        action, ac, info = actor.step(s, ac, k)
        s, out = env_step(s, action)
        return (s, ac), record(Step(action, info, out))

    (final, carry), steps = jax.lax.scan(body, (state, carry), jax.random.split(key, num_steps))
    return final, carry, steps
