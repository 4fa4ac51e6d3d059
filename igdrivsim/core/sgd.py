"""The one optimisation loop of every learner, the maze's and the driving benchmark's.

:func:`sgd_epochs` runs one pass (epoch) per key of ``epoch_keys``: the key draws a random
split of the data's ``size`` examples into ``minibatches`` equal minibatches, and each
minibatch is one optimiser step on ``loss_fn`` (``lax.scan`` over epochs, then over
minibatches). :func:`sgd_steps` is the step itself over any sequence of minibatch choices
(DAgger's draws from its buffer in the maze). The learning rate is an argument applied after
the optimiser's transformation (``params - lr * tx(grads)``: ``tx`` clips and scales, without a
learning rate of its own), so one compiled function serves any schedule.

``loss_fn(params, minibatch) -> (loss, aux)``; ``select(data, choice) -> minibatch`` picks a
minibatch (default: rows of every leaf, :func:`take_rows`). Both return the per-step ``aux``
stacked (``[epochs, minibatches, ...]`` from :func:`sgd_epochs`, ``[steps, ...]`` from
:func:`sgd_steps`) for the caller to reduce.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax


def clipped_adam(max_grad_norm: float, eps: float = 1e-8) -> optax.GradientTransformation:
    """Global-norm clipping then Adam's scaling, without a learning rate (the loop's ``lr``)."""
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.scale_by_adam(eps=eps))


def take_rows(data: Any, idx: jax.Array) -> Any:
    """The rows ``idx`` of every leaf of ``data`` (the example axis first)."""
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=0), data)


def sgd_steps(params, opt_state, data, loss_fn: Callable, tx: optax.GradientTransformation,
              lr, choices, select: Callable = take_rows, grad_norm: bool = False):
    """One optimiser step per entry of ``choices`` (a ``lax.scan``): ``(params, opt_state,
    aux [steps, ...])``. With ``grad_norm`` (``aux`` a dict) each step's ``aux`` also holds
    the global norm of its gradient (``"grad_norm"``, before clipping)."""
    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def step(carry, choice):
        params, opt_state = carry
        (_, aux), grads = grad_fn(params, select(data, choice))
        updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, jax.tree.map(lambda u: -lr * u, updates))
        if grad_norm:
            aux = {**aux, "grad_norm": optax.tree.norm(grads)}
        return (params, opt_state), aux

    (params, opt_state), aux = jax.lax.scan(step, (params, opt_state), choices)
    return params, opt_state, aux


def sgd_epochs(params, opt_state, data, loss_fn: Callable, tx: optax.GradientTransformation,
               epoch_keys: jax.Array, minibatches: int, lr, size: int | None = None,
               select: Callable = take_rows, grad_norm: bool = False):
    """``len(epoch_keys)`` passes over the ``size`` examples of ``data`` (default: the leading
    axis of its first leaf), each in ``minibatches`` random minibatches of ``size //
    minibatches`` (``size`` must be a multiple): ``(params, opt_state, aux [epochs,
    minibatches, ...])``. ``select(data, idx)`` takes the examples ``idx [size //
    minibatches]`` (another axis than the first: pass ``size`` and ``select``)."""
    if size is None:
        size = jax.tree.leaves(data)[0].shape[0]

    def epoch(carry, key):
        order = jax.random.permutation(key, size).reshape(minibatches, -1)
        params, opt_state, aux = sgd_steps(*carry, data, loss_fn, tx, lr, order, select,
                                           grad_norm)
        return (params, opt_state), aux

    (params, opt_state), aux = jax.lax.scan(epoch, (params, opt_state), epoch_keys)
    return params, opt_state, aux
