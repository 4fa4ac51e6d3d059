"""Small network parts shared by the maze's and the driving benchmark's flax networks."""

from __future__ import annotations

import jax


def dense_2d(layer, x: jax.Array) -> jax.Array:
    """``layer`` (a flax ``nn.Dense``) on ``x[..., D]`` as one 2-D matrix product (leading axes
    flattened).

    Under ``vmap`` over seeds, a dense layer on ``[T, B, N, D]`` inputs has a weight gradient
    that contracts over all leading axes at once, several times slower on XLA:CPU than the same
    contraction over one flattened axis.
    """
    return layer(x.reshape(-1, x.shape[-1])).reshape(*x.shape[:-1], -1)
