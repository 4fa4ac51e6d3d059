"""The policy's action distribution: three independent categoricals (dx, dy, dyaw bins).

Shapes: ``logits [..., 3, bins]`` and actions ``[..., 3]``. Lives with the policy (acting needs
it) so that ``policy`` does not import ``training``; ``training.losses`` re-exports it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def action_log_prob(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """log pi(a) = sum over the 3 dimensions of log softmax(logits)[a_d]; ``[...]``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    picked = jnp.take_along_axis(logp, actions[..., None].astype(jnp.int32), axis=-1)[..., 0]
    return picked.sum(-1)
