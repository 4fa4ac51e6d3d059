"""Line-of-sight geometry of :mod:`igdrivsim.observation.occlusion`, read and tested on its own."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from igdrivsim.observation.features import Observation, object_positions, roadgraph_positions

_EPS = 1e-6


def _blocked(targets: jax.Array, centres: jax.Array, heading: jax.Array, valid: jax.Array,
             half: jax.Array) -> jax.Array:
    """``bool[T, K]``: the segment origin -> ``targets[t]`` crosses box ``k`` (slab test;
    ``heading`` ``[K, 2]`` cos, sin; ``half`` the half length and width)."""
    cos, sin = heading[:, 0], heading[:, 1]

    def local(xy):  # [..., K, 2] points relative to each box, in the box's frame
        rel = xy - centres
        return jnp.stack([rel[..., 0] * cos + rel[..., 1] * sin,
                          -rel[..., 0] * sin + rel[..., 1] * cos], axis=-1)

    start = local(jnp.zeros((1, 2), jnp.float32))  # the ego, [1, K, 2]
    delta = local(targets[:, None, :]) - start  # [T, K, 2]
    parallel = jnp.abs(delta) < _EPS
    inside = jnp.abs(start) <= half
    safe = jnp.where(parallel, 1.0, delta)
    t1, t2 = (-half - start) / safe, (half - start) / safe
    low = jnp.where(parallel, jnp.where(inside, -jnp.inf, jnp.inf), jnp.minimum(t1, t2))
    high = jnp.where(parallel, jnp.where(inside, jnp.inf, -jnp.inf), jnp.maximum(t1, t2))
    enter = jnp.maximum(jnp.max(low, axis=-1), 0.0)
    leave = jnp.minimum(jnp.min(high, axis=-1), 1.0)
    ego_inside = jnp.all(inside, axis=-1)  # [1, K]
    return (enter <= leave) & valid[None, :] & ~ego_inside


def line_of_sight(obs: Observation, length: jax.Array | float, width: jax.Array | float
                  ) -> tuple[jax.Array, jax.Array]:
    """``(keep_objects bool[N_obj], keep_roadgraph bool[N_rg])`` for ONE example: True where
    the sight line from the ego is not blocked by another visible object's box."""
    centres = object_positions(obs)
    heading = obs.objects[:, 2:4]
    half = 0.5 * jnp.stack([jnp.asarray(length, jnp.float32), jnp.asarray(width, jnp.float32)])
    valid = obs.objects_valid
    n = centres.shape[0]
    blocked_obj = _blocked(centres, centres, heading, valid, half) & ~jnp.eye(n, dtype=bool)
    blocked_rg = _blocked(roadgraph_positions(obs), centres, heading, valid, half)
    return ~jnp.any(blocked_obj, axis=-1), ~jnp.any(blocked_rg, axis=-1)
