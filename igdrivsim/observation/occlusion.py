"""Line-of-sight occlusion: what lies behind another object's box, seen from the ego, is hidden.

A model beyond the paper's six (``--obs occlusion``, composable: ``occlusion+circular_r6``).
An object (its centre) or a road point is hidden when the straight segment from the ego (the
origin of the ego frame) to it crosses the box of another visible object. The observation does
not carry object sizes, so every occluder is a box of one fixed size (``length`` x ``width``,
default 4.5 m x 2.0 m, a typical passenger car) centred on its observed position and turned by
its observed heading; an object never occludes itself, and a box that contains the ego (an
overlap) occludes nothing. Road points under a box are hidden too (the segment enters the box).
Occluders are the objects still visible when the model runs: put it first in a composition so
that every object occludes (its data form, :class:`ObservationParams`, applies it first).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from igdrivsim.errors import ConfigError
from igdrivsim.observation.features import (
    Observation,
    hide_objects,
    hide_roadgraph,
    object_positions,
    roadgraph_positions,
)
from igdrivsim.observation.models import (
    ObservationModel,
    ObservationParams,
    ObservationSetting,
    register_setting,
)

_EPS = 1e-6


def _blocked(targets: jax.Array, centres: jax.Array, heading: jax.Array, valid: jax.Array,
             half: jax.Array) -> jax.Array:
    """``bool[T, K]``: the segment origin -> ``targets[t]`` crosses box ``k`` (slab test).

    ``centres f32[K, 2]``, ``heading f32[K, 2]`` (cos, sin), ``half f32[2]`` half length/width.
    """
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


def occlude(obs: Observation, length: jax.Array | float, width: jax.Array | float
            ) -> Observation:
    """``obs`` with everything hidden from the ego's line of sight removed (ONE example)."""
    keep_objects, keep_roadgraph = line_of_sight(obs, length, width)
    return hide_roadgraph(hide_objects(obs, keep_objects), keep_roadgraph)


@dataclass(frozen=True)
class LineOfSightOcclusion(ObservationModel):
    """Hides objects and road points behind other objects' boxes (``length`` x ``width`` m)."""

    length: float = 4.5
    width: float = 2.0

    def __post_init__(self) -> None:
        if not (self.length > 0 and self.width > 0):
            raise ConfigError(f"line-of-sight occlusion: length and width must be > 0, got "
                              f"{self.length} x {self.width}")

    def apply(self, obs, episode_key, step_key):
        return occlude(obs, self.length, self.width)

    def fold_params(self, params: ObservationParams, index: int) -> ObservationParams | None:
        hid_before = (params.fov_radius < float("inf") or params.fov_half_angle < float("inf")
                      or params.mask_p > 0 or params.occluder_length is not None)
        if hid_before:  # the data form occludes first; after another hiding: static program
            return None
        return params.replace(occluder_length=self.length, occluder_width=self.width)


register_setting(ObservationSetting("occlusion", (LineOfSightOcclusion(),)),
                 title="Line-of-sight occlusion", short="Occlusion")
