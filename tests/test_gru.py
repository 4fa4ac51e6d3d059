"""The sequence GRU's hand-written gradient matches autodiff through the plain scan."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.core.nn import _gru_forward, gru_scan


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


def test_gru_scan_is_flax_gru_cell_stepped():
    """With ``fused_gru_cell``'s parameters the scan equals stepping ``nn.GRUCell`` (state
    zeroed at the flagged steps), over two batch axes."""
    import flax.linen as nn

    from igdrivsim.core.nn import fused_gru_cell

    t, batch, d, h = 7, (2, 3), 5, 4
    keys = jax.random.split(jax.random.PRNGKey(1), 4)
    cell = nn.GRUCell(features=h)
    params = cell.init(keys[0], jnp.zeros((h,)), jnp.zeros((d,)))
    params = jax.tree.map(lambda p: p + 0.1 * jax.random.normal(keys[3], p.shape), params)
    xs = jax.random.normal(keys[1], (t, *batch, d))
    first = jax.random.bernoulli(keys[2], 0.3, (t, *batch))
    carry = jnp.ones((*batch, h))
    w_i, b_i, w_h, b_hn = fused_gru_cell(params["params"])
    last, seq = gru_scan(xs @ w_i + b_i, first, carry, w_h, b_hn)
    for step in range(t):
        carry = jnp.where(first[step][..., None], 0.0, carry)
        carry, out = cell.apply(params, carry, xs[step])
        np.testing.assert_allclose(seq[step], out, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(last, carry, rtol=1e-5, atol=1e-6)
