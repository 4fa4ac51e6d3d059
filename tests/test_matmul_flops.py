"""`bench train`'s FLOP count: a scan's body counts once per step, a vmapped batch and the
backward pass are priced, a cond runs one branch (XLA's cost analysis counts a loop once)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from igdrivsim.training.bench import matmul_flops

PRODUCT = 2 * 8 * 64 * 64  # one [8, 64] @ [64, 64]


def _loss(w, x):
    return (jax.lax.scan(lambda c, _: (jnp.tanh(c @ w), None), x, None, length=90)[0] ** 2).sum()


def test_scan_steps_backward_and_batch_are_counted():
    w, x = jnp.ones((64, 64)), jnp.ones((8, 64))
    # forward, and two products backward (into the carry and into w), at each of 90 steps
    assert matmul_flops(jax.jit(jax.grad(_loss)), w, x) == 3 * PRODUCT * 90
    batched = jax.vmap(jax.grad(_loss), in_axes=(None, 0))
    assert matmul_flops(batched, w, jnp.ones((5, 8, 64))) == 5 * 3 * PRODUCT * 90


def test_cond_counts_the_costlier_branch():
    w, x = jnp.ones((64, 64)), jnp.ones((8, 64))
    assert matmul_flops(lambda w, x: jax.lax.cond(x.sum() > 0, lambda: x @ w, lambda: x),
                        w, x) == PRODUCT
