"""The driving network's fast forms compute what their plain forms compute."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.policy.network import MLP, PooledMLP, dense_2d


def test_pooled_mlp_is_the_mlp_of_the_concatenation():
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    h = jax.random.normal(keys[0], (2, 3, 9, 6))  # [..., N points, D]
    pooled = jax.random.normal(keys[1], (2, 3, 6))
    fast = PooledMLP((8, 5))
    params = fast.init(keys[2], h, pooled)
    # the same parameter tree as an MLP on [h, pooled] (checkpoints carry over)
    concat = jnp.concatenate([h, jnp.broadcast_to(pooled[..., None, :], h.shape)], -1)
    plain = MLP((8, 5))
    assert (jax.tree.map(jnp.shape, params)
            == jax.tree.map(jnp.shape, plain.init(keys[2], concat)))
    np.testing.assert_allclose(fast.apply(params, h, pooled), plain.apply(params, concat),
                               rtol=1e-5, atol=1e-5)


def test_dense_2d_keeps_leading_axes():
    import flax.linen as nn

    x = jax.random.normal(jax.random.PRNGKey(1), (4, 3, 2, 7))
    layer = nn.Dense(5)
    params = layer.init(jax.random.PRNGKey(2), x)
    np.testing.assert_allclose(layer.apply(params, x),
                               jax.jit(lambda p, x: dense_2d(layer.bind(p), x))(params, x),
                               rtol=1e-5, atol=1e-6)
