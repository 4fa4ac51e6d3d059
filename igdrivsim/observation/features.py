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
from typing import Any

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


def to_frame(x: jax.Array, y: jax.Array, origin_xy: jax.Array, origin_yaw: jax.Array
             ) -> tuple[jax.Array, jax.Array]:
    """Global points ``(x, y)`` in the frame at ``origin_xy`` facing ``origin_yaw``."""
    return rotate_to_frame(x - origin_xy[..., 0], y - origin_xy[..., 1], origin_yaw)


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
    e = lambda a: a[..., None]  # noqa: E731
    onehot = (col == e(rtype) + 4) | (col == ROADGRAPH_FEATURES - 1)
    rg = jnp.where(col == 0, e(x), jnp.where(col == 1, e(y), jnp.where(
        col == 2, e(dir_x), jnp.where(col == 3, e(dir_y), onehot.astype(jnp.float32)))))
    return jnp.where(e(valid), rg, 0.0)


def roadgraph_kind(roadgraph: jax.Array) -> jax.Array:
    """Each row's road type ``int32[..., N]`` from its one-hot columns (0 for an invalid row)."""
    return jnp.argmax(roadgraph[..., ROADGRAPH_TYPES], axis=-1)


def object_features(sdc_xy: jax.Array, sdc_yaw: jax.Array, objects: Any, sdc_index: jax.Array,
                    num_objects: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The ``num_objects`` nearest valid other objects: ``(features f32[N, 6], valid, index)``."""
    ox, oy = to_frame(jnp.asarray(objects.x), jnp.asarray(objects.y), sdc_xy, sdc_yaw)
    obj_ok = jnp.asarray(objects.valid, bool) & (jnp.arange(ox.shape[-1]) != sdc_index)
    obj_idx, obj_valid = nearest(ox**2 + oy**2, obj_ok, num_objects)
    take = lambda a: jnp.take(jnp.asarray(a, jnp.float32), obj_idx, axis=-1)  # noqa: E731
    rel_yaw = take(objects.yaw) - sdc_yaw
    speed = jnp.hypot(take(objects.vel_x), take(objects.vel_y))
    obj = jnp.stack([take(ox) / POSITION_SCALE, take(oy) / POSITION_SCALE, jnp.cos(rel_yaw),
                     jnp.sin(rel_yaw), speed / SPEED_SCALE, jnp.ones_like(speed)], axis=-1)
    obj = jnp.where(obj_valid[..., None], obj, 0.0)
    return obj, obj_valid, obj_idx


def observe_arrays(sdc_xy: jax.Array, sdc_yaw: jax.Array, sdc_speed: jax.Array, objects: Any,
                   sdc_index: jax.Array, roadgraph: Any,
                   config: ObservationConfig = DEFAULT_CONFIG, sdc_yaw_rate: jax.Array = 0.0
                   ) -> tuple[Observation, Selection]:
    """``(observation, selection)`` of one example at the ego's (believed) pose ``sdc_xy``,
    ``sdc_yaw`` from global-frame ``objects`` (``x, y, yaw, vel_x, vel_y, valid`` ``[O]``, the
    ego in slot ``sdc_index``) and ``roadgraph`` (``xyz, dir, type, valid`` ``[R]``)."""
    sdc_xy, sdc_yaw = jnp.asarray(sdc_xy, jnp.float32), jnp.asarray(sdc_yaw, jnp.float32)
    obj, obj_valid, obj_idx = object_features(sdc_xy, sdc_yaw, objects, sdc_index,
                                              config.num_objects)

    xyz = jnp.asarray(roadgraph.xyz, jnp.float32)
    rx, ry = to_frame(xyz[..., 0], xyz[..., 1], sdc_xy, sdc_yaw)
    rg_idx, rg_valid = nearest(rx**2 + ry**2, jnp.asarray(roadgraph.valid, bool),
                               config.num_roadgraph_points)
    d = jnp.take(jnp.asarray(roadgraph.dir, jnp.float32), rg_idx, axis=-2)
    dx, dy = rotate_to_frame(d[..., 0], d[..., 1], sdc_yaw)
    rtype = jnp.take(jnp.asarray(roadgraph.type, jnp.int32), rg_idx, axis=-1)
    rg = roadgraph_features(jnp.take(rx, rg_idx) / POSITION_SCALE,
                            jnp.take(ry, rg_idx) / POSITION_SCALE, dx, dy, rtype, rg_valid)

    obs = Observation(
        objects=obj, objects_valid=obj_valid, roadgraph=rg, roadgraph_valid=rg_valid,
        sdc_speed=jnp.reshape(jnp.asarray(sdc_speed, jnp.float32) / SPEED_SCALE, (1,)),
        sdc_yaw_rate=jnp.reshape(jnp.asarray(sdc_yaw_rate, jnp.float32), (1,)),
    )
    return obs, Selection(object_index=obj_idx, roadgraph_index=rg_idx)


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
