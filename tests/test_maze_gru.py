"""The maze GRU's hand-written gradient matches autodiff through the plain scan."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from maze.network import _gru_forward, gru_scan


def test_gru_scan_gradient_matches_autodiff():
    t, b, h = 23, 5, 8
    keys = jax.random.split(jax.random.PRNGKey(0), 7)
    x = jax.random.normal(keys[0], (t, b, 3 * h))
    first = jax.random.bernoulli(keys[1], 0.15, (t, b)).at[0].set(True)
    h0 = jax.random.normal(keys[2], (b, h))
    w = 0.3 * jax.random.normal(keys[3], (h, 3 * h))
    bias = jax.random.normal(keys[4], (h,))
    c_last = jax.random.normal(keys[5], (b, h))
    c_seq = jax.random.normal(keys[6], (t, b, h))

    def loss(fn):
        def f(x, h0, w, bias):
            last, seq = fn(x, first, h0, w, bias)
            return (last * c_last).sum() + (jnp.sin(seq) * c_seq).sum()
        return f

    out, ref = gru_scan(x, first, h0, w, bias), _gru_forward(x, first, h0, w, bias)
    for a, r in zip(jax.tree.leaves(out), jax.tree.leaves(ref), strict=True):
        np.testing.assert_array_equal(a, r)
    got = jax.grad(loss(gru_scan), argnums=(0, 1, 2, 3))(x, h0, w, bias)
    want = jax.grad(loss(_gru_forward), argnums=(0, 1, 2, 3))(x, h0, w, bias)
    for g, r in zip(got, want, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-4, atol=1e-5)
    batched = jax.vmap(jax.grad(loss(gru_scan), argnums=2), (None, None, 0, None))(
        x, h0, jnp.stack([w, w]), bias)
    np.testing.assert_allclose(batched[1], want[2], rtol=1e-4, atol=1e-5)
