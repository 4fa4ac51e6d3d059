"""Recurrent actor-critic: a GRU on the raw observation, a linear actor (4 logits) and critic.

The GRU is written with fused gate matrices (one input and one recurrent matmul per step) and
the input projection of a whole sequence is computed before the time scan: the recurrent step
loop is the bottleneck on a CPU, so it does as little as possible (:func:`gru_scan`, with a
hand-written gradient). The hidden state is zeroed
at every episode start (``first``), unlike the original code whose state was never reset.
"""

from __future__ import annotations

import functools

import flax.linen as nn
import jax
import jax.numpy as jnp

from maze.env import MazeParams


def _split(x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The reset, update and candidate blocks of a fused ``[..., 3H]`` array."""
    hid = x.shape[-1] // 3
    return x[..., :hid], x[..., hid:2 * hid], x[..., 2 * hid:]


def _gru_forward(x_proj, first, h0, w_h, b_hn, save: bool = False):
    """The time loop; with ``save`` it also returns every step's gates for the backward pass."""
    # The gate inputs are split before the loop: slicing columns of a fused [B, 3H] input
    # inside the loop body made XLA:CPU's step ~2.5x slower.
    def step(h, inputs):
        x_r, x_z, x_n, start = inputs
        h = jnp.where(start[:, None], 0.0, h)
        hp_r, hp_z, hp_n = _split(h @ w_h)
        r = jax.nn.sigmoid(x_r + hp_r)
        z = jax.nn.sigmoid(x_z + hp_z)
        hn = hp_n + b_hn
        n = jnp.tanh(x_n + r * hn)
        h_new = (1.0 - z) * n + z * h
        # Saved gates leave the loop as one array: separate outputs made XLA:CPU recompute the
        # gate expressions once per output (2.5x slower steps).
        return h_new, ((h_new, jnp.concatenate([r, z, n], -1)) if save else h_new)

    return jax.lax.scan(step, h0, (*_split(x_proj), first))


@jax.custom_vjp
def gru_scan(x_proj, first, h0, w_h, b_hn):
    """GRU over ``x_proj[T, B, 3H]`` (input projection included) -> ``(h_T, hs[T, B, H])``.

    The gradient is hand-written: the forward pass keeps every step's gates, the backward loop
    carries only ``dh`` (one fused matmul and a few elementwise products per step), and what
    needs no loop (the candidate's recurrent input, the weights' gradient) is one matmul over
    the whole sequence.
    """
    return _gru_forward(x_proj, first, h0, w_h, b_hn)


def _gru_fwd(x_proj, first, h0, w_h, b_hn):
    h, (hs, rzn) = _gru_forward(x_proj, first, h0, w_h, b_hn, save=True)
    return (h, hs), (first, h0, w_h, b_hn, hs, rzn)


def _gru_bwd(res, grads):
    first, h0, w_h, b_hn, hs, rzn = res
    d_last, d_hs = grads
    r, z, n = _split(rzn)
    prev = jnp.where(first[..., None], 0.0, jnp.concatenate([h0[None], hs[:-1]]))
    hid = h0.shape[-1]
    hn = prev @ w_h[:, 2 * hid:] + b_hn  # one matmul over all steps (cheaper than saving it)
    a_n = (1.0 - z) * (1.0 - n * n)  # dh -> pre-activation of n
    # dh -> pre-activations of (r, z) and -> the recurrent n-block input (hp_n = prev @ w_n)
    gates = jnp.concatenate([a_n * hn * r * (1.0 - r), (prev - n) * z * (1.0 - z), a_n * r], -1)
    w_t = w_h.T

    def back(g, xs):
        d_out, gate, z_t, start = xs
        dh = g + d_out
        d_prev = dh * z_t + (jnp.concatenate([dh, dh, dh], -1) * gate) @ w_t
        return jnp.where(start[:, None], 0.0, d_prev), dh

    d_h0, dh = jax.lax.scan(back, d_last, (d_hs, gates, z, first), reverse=True)
    dh3 = jnp.concatenate([dh, dh, dh], -1)
    d_hp = dh3 * gates  # gradient of prev @ w_h
    d_x = d_hp.at[..., 2 * hid:].set(dh * a_n)  # the input's n-block is not gated by r
    # A plain 2-D matmul: the equivalent einsum over (t, b) was 2.5x slower on XLA:CPU.
    d_w = prev.reshape(-1, hid).T @ d_hp.reshape(-1, 3 * hid)
    return d_x, None, d_h0, d_w, d_hp[..., 2 * hid:].sum((0, 1))


gru_scan.defvjp(_gru_fwd, _gru_bwd)


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
            onehot = lambda x: (x[..., None] == cells).astype(obs.dtype).reshape(  # noqa: E731
                *x.shape[:-1], -1)
            parts += [visible, (goal - pos) * scale * visible, onehot(pos), onehot(goal)]
        return jnp.concatenate(parts, axis=-1)

    @nn.compact
    def __call__(self, h: jax.Array, obs: jax.Array, first: jax.Array):
        hid = self.hidden
        x_proj = _flat(nn.Dense(3 * hid, name="input"), self.features(obs))  # all steps at once
        w_h = self.param("recurrent", nn.initializers.orthogonal(), (hid, 3 * hid))
        b_hn = self.param("recurrent_bias", nn.initializers.zeros, (hid,))

        h, hs = gru_scan(x_proj, first, h, w_h, b_hn)
        logits = _flat(nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01),
                                name="actor"), hs)
        value = _flat(nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0), name="critic"), hs)
        if self.aux_head:
            aux = _flat(nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01),
                                 name="aux"), hs)
            return h, logits, value[..., 0], aux
        return h, logits, value[..., 0]


def _flat(layer: nn.Dense, x: jax.Array) -> jax.Array:
    """``layer`` on ``x[T, B, D]`` as one 2-D matmul: with the time and batch axes kept, the
    weight gradient (a contraction over both) was several times slower on XLA:CPU."""
    return layer(x.reshape(-1, x.shape[-1])).reshape(*x.shape[:-1], -1)


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


def init_stacked(model: GRUPolicy, key: jax.Array, num_seeds: int, obs_dim: int):
    """Parameters for ``num_seeds`` seeds, initialised one seed at a time and stacked.

    (Initialising under ``vmap`` was seen to hang in the orthogonal initialiser.)
    """
    init = _init_one(model, obs_dim)
    per_seed = [init(k) for k in jax.random.split(key, num_seeds)]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_seed)
