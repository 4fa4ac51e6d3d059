"""The policy's action distribution: three independent categoricals (dx, dy, dyaw bins).

Shapes: ``logits [..., 3, bins]`` and actions ``[..., 3]``. Lives with the policy (acting needs
it) so that ``policy`` does not import ``training``; ``training.losses`` re-exports it.
"""

from __future__ import annotations

import jax

from igdrivsim.core.losses import log_prob


def action_log_prob(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """log pi(a) = sum over the 3 dimensions of log softmax(logits)[a_d]; ``[...]``."""
    return log_prob(logits, actions).sum(-1)
