"""The network parts the maze's and the driving benchmark's flax networks share: a dense layer
as one 2-D product, and a GRU over a whole sequence, fast on a CPU: the input projection is one
product before the time scan, each step (forward and in the hand-written backward pass) one
recurrent matmul. The equations are flax's ``nn.GRUCell`` (:func:`fused_gru_cell` reads its
parameters): a network acts step by step with the cell and trains with :func:`gru_scan`.
:func:`matmul_flops` counts the products a function does (what the speed benchmarks divide).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import ClosedJaxpr, Jaxpr


def dense_2d(layer, x: jax.Array) -> jax.Array:
    """``layer`` (a flax ``nn.Dense``) on ``x[..., D]`` as one 2-D matrix product (leading axes
    flattened): its weight gradient then contracts one axis, several times faster on XLA:CPU."""
    return layer(x.reshape(-1, x.shape[-1])).reshape(*x.shape[:-1], -1)


def _split(x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The reset, update and candidate blocks of a fused ``[..., 3H]`` array."""
    hid = x.shape[-1] // 3
    return x[..., :hid], x[..., hid:2 * hid], x[..., 2 * hid:]


def _gru_forward(x_proj, first, h0, w_h, b_hn, save: bool = False):
    """The time loop; with ``save`` it also returns every step's gates for the backward pass."""
    # The gate inputs are split before the loop (slicing them inside is slower on XLA:CPU).
    def step(h, inputs):
        x_r, x_z, x_n, start = inputs
        h = jnp.where(start[..., None], 0.0, h)
        hp_r, hp_z, hp_n = _split(h @ w_h)
        r = jax.nn.sigmoid(x_r + hp_r)
        z = jax.nn.sigmoid(x_z + hp_z)
        hn = hp_n + b_hn
        n = jnp.tanh(x_n + r * hn)
        h_new = (1.0 - z) * n + z * h
        # Saved gates leave as one array (XLA:CPU recomputes them once per separate output).
        return h_new, ((h_new, jnp.concatenate([r, z, n], -1)) if save else h_new)

    return jax.lax.scan(step, h0, (*_split(x_proj), first))


@jax.custom_vjp
def gru_scan(x_proj, first, h0, w_h, b_hn):
    """GRU over ``x_proj[T, B..., 3H]`` (input projection included) -> ``(h_T, hs[T, B..., H])``.

    ``first[T, B...]`` zeroes the state before the flagged steps; ``w_h [H, 3H]``: the reset,
    update and candidate gates' recurrent kernels side by side; ``b_hn``: the candidate's
    recurrent bias. The hand-written gradient keeps every step's gates, carries only ``dh``
    through the backward loop, and computes what needs no loop in one matmul over the sequence.
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
    # dh -> pre-activations of (r, z) and the recurrent n-block input (three arrays: cheaper)
    g_r, g_z, g_n = a_n * hn * r * (1.0 - r), (prev - n) * z * (1.0 - z), a_n * r
    w_t = w_h.T

    def back(g, xs):
        d_out, gr, gz, gn, z_t, start = xs
        dh = g + d_out
        d_prev = dh * z_t + jnp.concatenate([dh * gr, dh * gz, dh * gn], -1) @ w_t
        return jnp.where(start[..., None], 0.0, d_prev), dh

    d_h0, dh = jax.lax.scan(back, d_last, (d_hs, g_r, g_z, g_n, z, first), reverse=True)
    d_x = jnp.concatenate([dh * g_r, dh * g_z, dh * a_n], -1)  # the input's n-block: not r-gated
    d_n = dh * g_n  # gradient of prev @ w_n
    # A plain 2-D matmul (faster on XLA:CPU than an einsum over (t, b)).
    d_w = prev.reshape(-1, hid).T @ jnp.concatenate([d_x[..., :2 * hid], d_n], -1).reshape(
        -1, 3 * hid)
    return d_x, None, d_h0, d_w, d_n.reshape(-1, hid).sum(0)


gru_scan.defvjp(_gru_fwd, _gru_bwd)


def fused_gru_cell(cell_params: dict) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``(w_i [D, 3H], b_i [3H], w_h [H, 3H], b_hn [H])`` from an ``nn.GRUCell``'s parameters
    (``ir``/``iz``/``in`` input and ``hr``/``hz``/``hn`` recurrent dense layers)."""
    p = cell_params
    w_i = jnp.concatenate([p["ir"]["kernel"], p["iz"]["kernel"], p["in"]["kernel"]], -1)
    b_i = jnp.concatenate([p["ir"]["bias"], p["iz"]["bias"], p["in"]["bias"]], -1)
    w_h = jnp.concatenate([p["hr"]["kernel"], p["hz"]["kernel"], p["hn"]["kernel"]], -1)
    return w_i, b_i, w_h, p["hn"]["bias"]


def matmul_flops(fn, *args) -> int:
    """Floating-point operations of the matrix products one call of ``fn`` does (a ``scan``
    body's times its length: XLA's cost analysis counts a loop's body once, so it cannot price
    a 90-step episode); the element-wise rest is left out, so a rate from it is a lower bound."""
    def count(jaxpr) -> int:
        total = 0
        for eqn in jaxpr.eqns:
            if eqn.primitive.name == "dot_general":
                (contract, _), _ = eqn.params["dimension_numbers"]
                lhs = eqn.invars[0].aval.shape
                total += 2 * int(np.prod(eqn.outvars[0].aval.shape)) * int(
                    np.prod([lhs[d] for d in contract]))
                continue
            inner = [count(getattr(j, "jaxpr", j)) for v in eqn.params.values()
                     for j in (v if isinstance(v, tuple) else (v,))
                     if isinstance(j, (Jaxpr, ClosedJaxpr))]
            if eqn.primitive.name == "cond":
                total += max(inner, default=0)  # one branch runs
            else:
                total += sum(inner) * int(eqn.params.get("length", 1))
        return total

    return count(jax.make_jaxpr(fn)(*args).jaxpr)
