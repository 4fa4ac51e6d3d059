"""The observation pipeline: believed pose -> SDC-frame features -> hiding, for one example.

``observe(source, setting, episode_key, step_key)`` is what training and evaluation call at
every step, on a simulator state or one step of a recorded episode (:class:`ObservationRecord`).

What the ego sees along the (deterministic) logged episode is recorded once per dataset
(:func:`igdrivsim.training.records.compute_records`) in the TRUE ego frame, beyond the
capacities (:func:`superset_config`). Observing a recorded step shifts it by the believed
pose's offset and re-selects the nearest: the simulator's observation exactly without noise,
and with noise while the offset stays below the radius of the ``N`` nearest points.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.observation.features import (
    DEFAULT_CONFIG,
    POSITION_SCALE,
    SPEED_SCALE,
    Observation,
    ObservationConfig,
    Selection,
    nearest,
    roadgraph_features,
    rotate_to_frame,
)
from igdrivsim.observation.models import ObservationSetting, apply_setting, perceive_pose
from igdrivsim.simulator import current_objects, sdc_yaw_rate


@struct.dataclass
class ObservationRecord:
    """One scenario's teacher-forced episode (``[..., T=90]``): the features of the ``K``
    objects and ``M`` roadgraph points nearest the true pose, and the discretised expert's
    labels of the 80 controlled steps (``None`` in a one-step slice)."""

    objects: jax.Array  # f32[..., T, K, 6]
    objects_valid: jax.Array  # bool[..., T, K]
    roadgraph: jax.Array  # f32[..., T, M, 4]: x, y, dir_x, dir_y
    roadgraph_type: jax.Array  # int8[..., T, M]
    roadgraph_valid: jax.Array  # bool[..., T, M]
    sdc_speed: jax.Array  # f32[..., T, 1]
    sdc_yaw_rate: jax.Array  # f32[..., T, 1]
    sdc_yaw: jax.Array  # f32[..., T]
    actions: jax.Array  # int16[..., 80, 3]
    action_valid: jax.Array  # bool[..., 80]


def superset_config(obs: ObservationConfig, max_objects: int) -> ObservationConfig:
    """What is recorded: every other object slot and four times the observed roadgraph points."""
    return ObservationConfig(max(obs.num_objects, max_objects - 1), 4 * obs.num_roadgraph_points)


def observe_record(rec: ObservationRecord, setting, episode_key: jax.Array,
                   step_key: jax.Array, config: ObservationConfig) -> Observation:
    """The observation of one recorded step under ``setting`` (one example)."""
    offset, _ = perceive_pose(setting, jnp.zeros((2,), jnp.float32), rec.sdc_yaw, episode_key,
                              step_key)
    shift = jnp.stack(rotate_to_frame(offset[0], offset[1], rec.sdc_yaw)) / POSITION_SCALE
    moved = jnp.any(shift != 0)

    def pick(xy, valid, n):
        idx, ok = nearest(jnp.sum((xy - shift) ** 2, -1), valid, n)
        return jnp.where(moved, idx, jnp.arange(n)), jnp.where(moved, ok, valid[:n])

    oi, ov = pick(rec.objects[:, :2], rec.objects_valid, config.num_objects)
    objects = jnp.where(ov[:, None], rec.objects[oi].at[:, :2].add(-shift), 0.0)
    ri, rv = pick(rec.roadgraph[:, :2], rec.roadgraph_valid, config.num_roadgraph_points)
    rg4 = rec.roadgraph[ri].at[:, :2].add(-shift)
    rg = roadgraph_features(*rg4.T, rec.roadgraph_type[ri].astype(jnp.int32), rv)
    obs = Observation(objects=objects, objects_valid=ov, roadgraph=rg, roadgraph_valid=rv,
                      sdc_speed=rec.sdc_speed, sdc_yaw_rate=rec.sdc_yaw_rate)
    return apply_setting(setting, obs, episode_key, step_key)


def episode_observations(rec: ObservationRecord, setting, episode_key: jax.Array,
                         config: ObservationConfig) -> Observation:
    """All 90 observations of one recorded episode, ``[T, ...]`` (step key ``fold_in(episode
    key, t)``, as on the simulator state at step ``t``)."""
    steps = jnp.arange(rec.sdc_yaw.shape[0])
    per_step = rec.replace(actions=None, action_valid=None)  # the labels have 80 steps, not 90
    return jax.vmap(lambda r, t: observe_record(
        r, setting, episode_key, jax.random.fold_in(episode_key, t), config))(per_step, steps)


def observe_setting_arrays(sdc_xy: jax.Array, sdc_yaw: jax.Array, sdc_speed: jax.Array,
                           objects: Any, sdc_index: jax.Array, roadgraph: Any,
                           setting: ObservationSetting, episode_key: jax.Array,
                           step_key: jax.Array, config: ObservationConfig = DEFAULT_CONFIG,
                           sdc_yaw_rate: jax.Array = 0.0) -> tuple[Observation, Selection]:
    """``(observation, selection)`` of one example under ``setting`` from the ego's TRUE pose
    ``sdc_xy``, ``sdc_yaw``, global-frame ``objects`` (``x, y, yaw, vel_x, vel_y, valid``
    ``[O]``, the ego in slot ``sdc_index``) and ``roadgraph`` (``xyz, dir, type, valid``
    ``[R]``): the nearest around the believed pose, then the setting's hiding."""
    xy, yaw = perceive_pose(setting, jnp.asarray(sdc_xy, jnp.float32),
                            jnp.asarray(sdc_yaw, jnp.float32), episode_key, step_key)
    ox, oy = rotate_to_frame(jnp.asarray(objects.x) - xy[..., 0],
                             jnp.asarray(objects.y) - xy[..., 1], yaw)
    obj_ok = jnp.asarray(objects.valid, bool) & (jnp.arange(ox.shape[-1]) != sdc_index)
    obj_idx, obj_valid = nearest(ox**2 + oy**2, obj_ok, config.num_objects)
    take = lambda a: jnp.take(jnp.asarray(a, jnp.float32), obj_idx, axis=-1)
    rel_yaw = take(objects.yaw) - yaw
    speed = jnp.hypot(take(objects.vel_x), take(objects.vel_y))
    obj = jnp.stack([take(ox) / POSITION_SCALE, take(oy) / POSITION_SCALE, jnp.cos(rel_yaw),
                     jnp.sin(rel_yaw), speed / SPEED_SCALE, jnp.ones_like(speed)], axis=-1)

    xyz = jnp.asarray(roadgraph.xyz, jnp.float32)
    rx, ry = rotate_to_frame(xyz[..., 0] - xy[..., 0], xyz[..., 1] - xy[..., 1], yaw)
    rg_idx, rg_valid = nearest(rx**2 + ry**2, jnp.asarray(roadgraph.valid, bool),
                               config.num_roadgraph_points)
    d = jnp.take(jnp.asarray(roadgraph.dir, jnp.float32), rg_idx, axis=-2)
    dx, dy = rotate_to_frame(d[..., 0], d[..., 1], yaw)
    rtype = jnp.take(jnp.asarray(roadgraph.type, jnp.int32), rg_idx, axis=-1)
    rg = roadgraph_features(jnp.take(rx, rg_idx) / POSITION_SCALE,
                            jnp.take(ry, rg_idx) / POSITION_SCALE, dx, dy, rtype, rg_valid)

    obs = Observation(
        objects=jnp.where(obj_valid[..., None], obj, 0.0), objects_valid=obj_valid,
        roadgraph=rg, roadgraph_valid=rg_valid,
        sdc_speed=jnp.reshape(jnp.asarray(sdc_speed, jnp.float32) / SPEED_SCALE, (1,)),
        sdc_yaw_rate=jnp.reshape(jnp.asarray(sdc_yaw_rate, jnp.float32), (1,)),
    )
    return apply_setting(setting, obs, episode_key, step_key), Selection(obj_idx, rg_idx)


def observe_with_selection(state: Any, setting: ObservationSetting, episode_key: jax.Array,
                           step_key: jax.Array, config: ObservationConfig = DEFAULT_CONFIG
                           ) -> tuple[Observation, Selection]:
    """:func:`observe` that also returns which object / roadgraph slots were selected."""
    objects, i = current_objects(state), state.sdc_index
    x, y, yaw, vx, vy = (jnp.take(jnp.asarray(a, jnp.float32), i, axis=-1)
                         for a in (objects.x, objects.y, objects.yaw, objects.vel_x, objects.vel_y))
    return observe_setting_arrays(jnp.stack([x, y], axis=-1), yaw, jnp.hypot(vx, vy), objects, i,
                                  state.roadgraph, setting, episode_key, step_key, config,
                                  sdc_yaw_rate(state))


def observe(source: Any, setting: ObservationSetting, episode_key: jax.Array,
            step_key: jax.Array, config: ObservationConfig = DEFAULT_CONFIG) -> Observation:
    """The imitator's observation (one example) under ``setting``, of a simulator state or of
    one recorded step: the SAME ``episode_key`` at every step of an episode, a fresh
    ``step_key`` per step (e.g. ``fold_in(episode_key, state.timestep)``)."""
    if isinstance(source, ObservationRecord):
        return observe_record(source, setting, episode_key, step_key, config)
    return observe_with_selection(source, setting, episode_key, step_key, config)[0]
