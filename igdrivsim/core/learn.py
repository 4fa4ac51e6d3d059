"""What the maze's and the driving benchmark's learners share: the loss terms of categorical
policies and the one optimisation loop.

The loss terms take explicit arrays, reduce the last (class) axis only and read sequences
time-major. :func:`sgd_epochs` / :func:`sgd_steps` apply the learning rate after the
optimiser's transformation (``params - lr * tx(grads)``): one compiled function, any schedule.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax


def masked_mean(x: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """Mean of ``x`` over the entries where ``mask`` (broadcast to ``x``) holds; all if None."""
    if mask is None:
        return x.mean()
    mask = jnp.broadcast_to(mask, x.shape).astype(x.dtype)
    return (x * mask).sum() / jnp.maximum(mask.sum(), 1.0)


def normalize(x: jax.Array, mask: jax.Array | None = None, eps: float = 1e-8) -> jax.Array:
    """Zero-mean unit-std advantages (statistics over the masked entries)."""
    mean = masked_mean(x, mask)
    std = jnp.sqrt(masked_mean((x - mean) ** 2, mask))
    return (x - mean) / (std + eps)


def log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """``log softmax(logits)[action]``: logits ``[..., K]``, action ``[...]`` -> ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def entropy(logits: jax.Array) -> jax.Array:
    """Entropy of the categorical, ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(logp) * logp).sum(-1)


def soft_cross_entropy(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """``-sum_a p_target(a) log p(a)`` to a target given by its log-probabilities, ``[...]``
    (the KL's minimiser, without the target's entropy)."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(target_logp) * logp).sum(-1)


def kl_divergence(target_logp: jax.Array, logits: jax.Array) -> jax.Array:
    """``KL(target || policy)``, ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return (jnp.exp(target_logp) * (target_logp - logp)).sum(-1)


def gae(values: jax.Array, rewards: jax.Array, dones: jax.Array, last_value: jax.Array,
        gamma: float, lam: float, axis: int = 0) -> tuple[jax.Array, jax.Array]:
    """``(advantages, returns)`` shaped like ``rewards`` along the time axis ``axis``:
    ``rewards[t]`` follows the action at ``t``, ``values[t] = V(s_t)``, ``dones[t]``: the episode
    ended with that step (no bootstrap across it), ``last_value = V(s_T)`` shaped like one step."""
    keep = 1.0 - dones.astype(values.dtype)
    next_values = jnp.concatenate(
        [jax.lax.slice_in_dim(values, 1, None, axis=axis),
         jnp.expand_dims(last_value, axis)], axis=axis)
    deltas = rewards + gamma * next_values * keep - values

    def back(adv, xs):
        delta, keep_t = xs
        adv = delta + gamma * lam * keep_t * adv
        return adv, adv

    time_major = (jnp.moveaxis(deltas, axis, 0), jnp.moveaxis(keep, axis, 0))
    _, adv = jax.lax.scan(back, jnp.zeros_like(time_major[0][0]), time_major, reverse=True)
    adv = jnp.moveaxis(adv, 0, axis)
    return adv, adv + values


def surrogate_terms(logp_new: jax.Array, logp_old: jax.Array, advantages: jax.Array,
                    clip: float) -> jax.Array:
    """Per-state PPO policy loss ``-min(r A, clip(r, 1-eps, 1+eps) A)``, ``[...]``."""
    ratio = jnp.exp(logp_new - logp_old)
    return -jnp.minimum(ratio * advantages, jnp.clip(ratio, 1.0 - clip, 1.0 + clip) * advantages)


def value_loss(values: jax.Array, returns: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """0.5 * mean squared error; both arguments must have the same shape (no broadcasting)."""
    if values.shape != returns.shape:
        raise ValueError(f"value_loss: values {values.shape} vs returns {returns.shape}")
    return 0.5 * masked_mean((values - returns) ** 2, mask)


def clipped_value_loss(values: jax.Array, old_values: jax.Array, returns: jax.Array,
                       clip: float) -> jax.Array:
    """PPO's clipped value loss: ``0.5 mean max((v - R)^2, (v_old + clip(v - v_old) - R)^2)``."""
    clipped = old_values + jnp.clip(values - old_values, -clip, clip)
    return 0.5 * jnp.maximum((values - returns) ** 2, (clipped - returns) ** 2).mean()


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
    """``(params, opt_state, aux [epochs, minibatches, ...])`` of ``len(epoch_keys)`` passes over
    the ``size`` examples of ``data`` (default: its first leaf's leading axis), each in
    ``minibatches`` random minibatches; ``select(data, idx)`` takes the examples ``idx``."""
    if size is None:
        size = jax.tree.leaves(data)[0].shape[0]

    def epoch(carry, key):
        order = jax.random.permutation(key, size).reshape(minibatches, -1)
        params, opt_state, aux = sgd_steps(*carry, data, loss_fn, tx, lr, order, select, grad_norm)
        return (params, opt_state), aux

    (params, opt_state), aux = jax.lax.scan(epoch, (params, opt_state), epoch_keys)
    return params, opt_state, aux
