"""The SDC-frame observation: nearest objects and roadgraph points around the ego, as features.

Pure functions of plain arrays for ONE example (batch with ``jax.vmap``), in the frame of the
ego's *believed* pose (origin its position, ``+x`` its heading). Feature layout (the contract
with :mod:`igdrivsim.policy`), nearest first, invalid (padding or hidden) slots all zero:

* ``objects f32[N_obj, 6]``: ``x/100, y/100, cos(yaw), sin(yaw), speed/50, valid`` (yaw relative
  to the ego heading; the SDC excluded).
* ``roadgraph f32[N_rg, 25]``: ``x/100, y/100, dir_x, dir_y``, one-hot type (20), ``valid``.
* ``sdc_speed f32[1]``: ego speed / 50; ``sdc_yaw_rate f32[1]``: its heading change over the
  last step in rad/s (odometry).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.data.scenario import RG_NUM_TYPES
from igdrivsim.errors import ConfigError

POSITION_SCALE = 100.0  # metres -> feature units
SPEED_SCALE = 50.0  # m/s -> feature units
OBJECT_FEATURES = 6  # x, y, cos and sin of the relative yaw, speed, valid
OBJECT_SPEED = 4  # the speed's column
ROADGRAPH_FEATURES = 4 + RG_NUM_TYPES + 1  # xy, dir xy, one-hot type, valid = 25
ROADGRAPH_GEOMETRY = slice(0, 4)  # x/100, y/100, dir_x, dir_y
ROADGRAPH_TYPES = slice(4, 4 + RG_NUM_TYPES)  # the one-hot type


@dataclass(frozen=True)
class ObservationConfig:
    """Observation capacities (paper: 32 nearest objects, 1,500 nearest roadgraph points)."""

    num_objects: int = 32
    num_roadgraph_points: int = 1500

    def __post_init__(self) -> None:
        if self.num_objects < 1 or self.num_roadgraph_points < 1:
            raise ConfigError(
                f"observation capacities must be >= 1, got num_objects={self.num_objects}, "
                f"num_roadgraph_points={self.num_roadgraph_points}")


DEFAULT_CONFIG = ObservationConfig()


@struct.dataclass
class Observation:
    """What the policy sees at one step (shapes for one example; any leading batch axes allowed)."""

    objects: jax.Array  # f32[..., N_obj, 6]
    objects_valid: jax.Array  # bool[..., N_obj]
    roadgraph: jax.Array  # f32[..., N_rg, 25]
    roadgraph_valid: jax.Array  # bool[..., N_rg]
    sdc_speed: jax.Array  # f32[..., 1]
    sdc_yaw_rate: jax.Array  # f32[..., 1]


@struct.dataclass
class Selection:
    """Which source slots fill the observation (for pictures and debugging), nearest first."""

    object_index: jax.Array  # int32[..., N_obj], index into the scene's object axis
    roadgraph_index: jax.Array  # int32[..., N_rg], index into the (cropped) roadgraph axis


def rotate_to_frame(vx: jax.Array, vy: jax.Array, origin_yaw: jax.Array
                    ) -> tuple[jax.Array, jax.Array]:
    """Direction vectors ``(vx, vy)`` expressed in a frame rotated by ``origin_yaw``."""
    c, s = jnp.cos(origin_yaw), jnp.sin(origin_yaw)
    return c * vx + s * vy, -s * vx + c * vy


def nearest(d2: jax.Array, valid: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
    """Indices of the ``k`` valid entries with smallest ``d2`` (nearest first, ``lax.top_k``) and
    their validity (padded with index 0, invalid, below ``k`` candidates)."""
    n = d2.shape[-1]
    score = jnp.where(valid, -d2, -jnp.inf)
    _, idx = jax.lax.top_k(score, min(k, n))
    sel_valid = jnp.take_along_axis(valid, idx, axis=-1)
    if k > n:
        pad = [(0, 0)] * (idx.ndim - 1) + [(0, k - n)]
        idx, sel_valid = jnp.pad(idx, pad), jnp.pad(sel_valid, pad)
    return idx.astype(jnp.int32), sel_valid


def roadgraph_features(x: jax.Array, y: jax.Array, dir_x: jax.Array, dir_y: jax.Array,
                       rtype: jax.Array, valid: jax.Array) -> jax.Array:
    """The ``f32[..., 25]`` roadgraph features of points already in the ego frame and scaled (one
    elementwise select over the feature axis: XLA:CPU fuses it, ~4x faster than concatenating)."""
    col = jnp.arange(ROADGRAPH_FEATURES)
    e = lambda a: a[..., None]
    onehot = (col == e(rtype) + 4) | (col == ROADGRAPH_FEATURES - 1)
    rg = jnp.where(col == 0, e(x), jnp.where(col == 1, e(y), jnp.where(
        col == 2, e(dir_x), jnp.where(col == 3, e(dir_y), onehot.astype(jnp.float32)))))
    return jnp.where(e(valid), rg, 0.0)


def roadgraph_kind(roadgraph: jax.Array) -> jax.Array:
    """Each row's road type ``int32[..., N]`` from its one-hot columns (0 for an invalid row)."""
    return jnp.argmax(roadgraph[..., ROADGRAPH_TYPES], axis=-1)


def object_positions(obs: Observation) -> jax.Array:
    """Object centres in metres in the (believed) ego frame, ``f32[..., N_obj, 2]``."""
    return obs.objects[..., 0:2] * POSITION_SCALE


def roadgraph_positions(obs: Observation) -> jax.Array:
    """Roadgraph points in metres in the (believed) ego frame, ``f32[..., N_rg, 2]``."""
    return obs.roadgraph[..., 0:2] * POSITION_SCALE


def hide_objects(obs: Observation, keep: jax.Array) -> Observation:
    """Hide the object slots where ``keep`` is False: invalid and all-zero features."""
    valid = obs.objects_valid & keep
    return obs.replace(objects=jnp.where(valid[..., None], obs.objects, 0.0), objects_valid=valid)


def hide_roadgraph(obs: Observation, keep: jax.Array) -> Observation:
    """Hide the roadgraph slots where ``keep`` is False: invalid and all-zero features."""
    valid = obs.roadgraph_valid & keep
    return obs.replace(roadgraph=jnp.where(valid[..., None], obs.roadgraph, 0.0),
                       roadgraph_valid=valid)
