"""Recurrent actor-critic: a GRU on the raw observation, a linear actor (4 logits) and critic.

The GRU is written with fused gate matrices (one input and one recurrent matmul per step) and
the input projection of a whole sequence is computed before the time scan: the recurrent step
loop is the bottleneck on a CPU, so it does as little as possible. The hidden state is zeroed
at every episode start (``first``), unlike the original code whose state was never reset.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from maze.env import MazeParams


class GRUPolicy(nn.Module):
    """``(h, obs[T, B, D], first[T, B]) -> (h_T, logits[T, B, A], value[T, B])``."""

    hidden: int = 128
    num_actions: int = 4
    coord_scale: float = 1.0 / 14.0  # positions are divided by the array side (raw obs otherwise)
    patch_size: int = 9  # leading wall-patch entries (left unscaled)

    @nn.compact
    def __call__(self, h: jax.Array, obs: jax.Array, first: jax.Array):
        hid = self.hidden
        scale = jnp.where(jnp.arange(obs.shape[-1]) < self.patch_size, 1.0, self.coord_scale)
        x_proj = nn.Dense(3 * hid, name="input")(obs * scale)  # [T, B, 3H], all steps at once
        w_h = self.param("recurrent", nn.initializers.orthogonal(), (hid, 3 * hid))
        b_hn = self.param("recurrent_bias", nn.initializers.zeros, (hid,))

        def cell(h, inputs):
            xp, start = inputs
            h = jnp.where(start[:, None], 0.0, h)
            hp = h @ w_h
            r = jax.nn.sigmoid(xp[:, :hid] + hp[:, :hid])
            z = jax.nn.sigmoid(xp[:, hid:2 * hid] + hp[:, hid:2 * hid])
            n = jnp.tanh(xp[:, 2 * hid:] + r * (hp[:, 2 * hid:] + b_hn))
            h = (1.0 - z) * n + z * h
            return h, h

        h, hs = jax.lax.scan(cell, h, (x_proj, first))
        logits = nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01),
                          name="actor")(hs)
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0), name="critic")(hs)
        return h, logits, value[..., 0]


def make_policy(hidden: int, params: MazeParams) -> GRUPolicy:
    return GRUPolicy(hidden=hidden, coord_scale=1.0 / (params.size + 1),
                     patch_size=params.receptive_field**2)


def init_stacked(model: GRUPolicy, key: jax.Array, num_seeds: int, obs_dim: int):
    """Parameters for ``num_seeds`` seeds, initialised one seed at a time and stacked.

    (Initialising under ``vmap`` was seen to hang in the orthogonal initialiser.)
    """
    init = jax.jit(lambda k: model.init(k, jnp.zeros((1, model.hidden)),
                                        jnp.zeros((1, 1, obs_dim)), jnp.ones((1, 1), bool)))
    keys = jax.random.split(key, num_seeds)
    per_seed = [init(k) for k in keys]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_seed)
