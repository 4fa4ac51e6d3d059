"""Recurrent actor-critic: a GRU on the raw observation, a linear actor (4 logits) and critic.

The GRU is :func:`igdrivsim.core.nn.gru_scan` (fused gates, the input projection of a whole
sequence before the time scan, a hand-written gradient): the recurrent step loop is the
bottleneck on a CPU, so it does as little as possible. The hidden state is zeroed
at every episode start (``first``), unlike the original code whose state was never reset.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from igdrivsim.core.nn import dense_2d, gru_scan
from maze.env import MazeParams


class GRUPolicy(nn.Module):
    """``(h, obs[T, B, D], first[T, B]) -> (h_T, logits[T, B, A], value[T, B])``.

    With ``aux_head`` a fourth output, ``aux_logits[T, B, A]``, shares the GRU trunk."""

    hidden: int = 128
    num_actions: int = 4
    side: int = 15  # maze array side; coordinates are divided by ``side - 1``
    patch_size: int = 9  # leading wall-patch entries
    encoding: str = "onehot"  # "raw" (scaled obs only) or "onehot" (see ``features``)
    aux_head: bool = False  # also return an imitation-only actor head (ADVISOR, maze.mixed)

    def features(self, obs: jax.Array) -> jax.Array:
        """Input features computed from the observation (no extra information).

        ``raw``: the observation with coordinates scaled to [0, 1]. ``onehot`` adds a goal-visible
        flag, the goal offset from the agent (0 when hidden) and one-hot rows and columns of the
        agent and the goal: a position-to-action map (what an exploring policy needs) is then
        linear in the input, which makes partial-observation PPO learn several times faster.
        """
        patch, pos, goal = (obs[..., :self.patch_size], obs[..., self.patch_size:-2],
                            obs[..., -2:])
        scale = 1.0 / (self.side - 1)
        parts = [patch, pos * scale, goal * scale]
        if self.encoding == "onehot":
            visible = (goal[..., :1] >= 0).astype(obs.dtype)
            cells = jnp.arange(self.side)
            onehot = lambda x: (x[..., None] == cells).astype(obs.dtype).reshape(
                *x.shape[:-1], -1)
            parts += [visible, (goal - pos) * scale * visible, onehot(pos), onehot(goal)]
        return jnp.concatenate(parts, axis=-1)

    @nn.compact
    def __call__(self, h: jax.Array, obs: jax.Array, first: jax.Array):
        hid = self.hidden
        x_proj = dense_2d(nn.Dense(3 * hid, name="input"), self.features(obs))  # all steps at once
        w_h = self.param("recurrent", nn.initializers.orthogonal(), (hid, 3 * hid))
        b_hn = self.param("recurrent_bias", nn.initializers.zeros, (hid,))

        h, hs = gru_scan(x_proj, first, h, w_h, b_hn)
        logits = dense_2d(nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01),
                                   name="actor"), hs)
        value = dense_2d(nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0),
                                  name="critic"), hs)
        if self.aux_head:
            aux = dense_2d(nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01),
                                name="aux"), hs)
            return h, logits, value[..., 0], aux
        return h, logits, value[..., 0]


def make_policy(hidden: int, params: MazeParams, encoding: str = "onehot",
                aux_head: bool = False) -> GRUPolicy:
    return GRUPolicy(hidden=hidden, side=params.size + 2, patch_size=params.receptive_field**2,
                     encoding=encoding, aux_head=aux_head)


def without_aux(net_params):
    """Parameters of the plain policy (drops the ``aux`` head; works on stacked params)."""
    return {"params": {k: v for k, v in net_params["params"].items() if k != "aux"}}


@functools.cache
def _init_one(model: GRUPolicy, obs_dim: int):
    """Jitted single-seed initialiser, compiled once per model (not once per call)."""
    return jax.jit(lambda k: model.init(k, jnp.zeros((1, model.hidden)),
                                        jnp.zeros((1, 1, obs_dim)), jnp.ones((1, 1), bool)))


def init_stacked(model: GRUPolicy, key: jax.Array, num_seeds: int, obs_dim: int,
                 which: Sequence[int] | None = None):
    """Parameters for ``num_seeds`` seeds (only the seeds ``which``, when given: a part of the
    seeds gets the parameters it has in the whole), initialised one seed at a time and stacked.

    (Initialising under ``vmap`` was seen to hang in the orthogonal initialiser.)
    """
    init = _init_one(model, obs_dim)
    keys = jax.random.split(key, num_seeds)
    per_seed = [init(keys[i]) for i in (range(num_seeds) if which is None else which)]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_seed)
